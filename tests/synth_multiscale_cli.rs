//! `surfsynth synth --method multiscale` end to end through the binary: full coverage, the
//! method recorded in report.json, seams no worse than the acceptance bound of issue 5.

use std::process::Command;

/// OBJ text of a k x k grid of unit quads in the z = 0 plane, bent by
/// z = bend · sin(0.7x) · cos(0.5y) (0: flat).
fn grid_obj(k: usize, bend: f64) -> String {
    let mut obj = String::new();
    for y in 0..=k {
        for x in 0..=k {
            let z = bend * ((x as f64) * 0.7).sin() * ((y as f64) * 0.5).cos();
            obj += &format!("v {x} {y} {z}\n");
        }
    }
    for y in 0..k {
        for x in 0..k {
            let i = y * (k + 1) + x + 1;
            obj += &format!("f {} {} {} {}\n", i, i + 1, i + k + 2, i + k + 1);
        }
    }
    obj
}

#[test]
fn multiscale_runs_from_the_cli() {
    let dir = tempfile::tempdir().unwrap();
    // A 4x4 grid of unit quads, slightly bent so it is not flat.
    let mesh = dir.path().join("grid.obj");
    std::fs::write(&mesh, grid_obj(4, 0.1)).unwrap();
    let example = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/gravel.png");
    // Single seeds range 0.90-1.20 here (seeds 0-7, before and after the coarsest-level
    // fetch fix alike: means 1.05 and 1.05), so the bound applies to the mean of 8 seeds.
    let mut seams = Vec::new();
    for seed in 0..8 {
        let out = dir.path().join(format!("out{seed}"));
        let status = Command::new(env!("CARGO_BIN_EXE_surfsynth"))
            .args(["synth", "--mesh"])
            .arg(&mesh)
            .args([
                "--example",
                example,
                "--method",
                "multiscale",
                "--resolution",
                "16",
                "--seed",
                &seed.to_string(),
                "--out",
            ])
            .arg(&out)
            .output()
            .unwrap();
        assert!(
            status.status.success(),
            "{}",
            String::from_utf8_lossy(&status.stderr)
        );
        let report: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap())
                .unwrap();
        assert_eq!(report["method"], "multiscale");
        assert!(report["multiscale"].is_object());
        let q = surfsynth::eval::evaluate(&out, None).unwrap();
        assert_eq!(q.coverage, 1.0);
        seams.push(q.seam_ratio.unwrap());
    }
    let mean = seams.iter().sum::<f64>() / seams.len() as f64;
    eprintln!("seam ratios {seams:.3?}, mean {mean:.3}");
    assert!(mean <= 1.15, "seam ratios {seams:?}");
}

#[test]
fn search_flag_selects_ann_and_is_refused_for_the_coherent_method() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/fixtures/spot_control_mesh.obj"
    );
    let example = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/gravel.png");
    let run = |extra: &[&str], out: &std::path::Path| {
        Command::new(env!("CARGO_BIN_EXE_surfsynth"))
            .args(["synth", "--mesh", mesh, "--example", example])
            .args(["--resolution", "4"])
            .args(extra)
            .arg("--out")
            .arg(out)
            .output()
            .unwrap()
    };
    for search in ["ann", "kcoherence"] {
        let out = dir.path().join(search);
        let o = run(&["--method", "multiscale", "--search", search], &out);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let report = surfsynth::report::read(&out).unwrap();
        assert_eq!(report["multiscale"]["search"], search);
        assert_eq!(surfsynth::eval::evaluate(&out, None).unwrap().coverage, 1.0);
    }
    let out = dir.path().join("coherent");
    let o = run(&["--search", "ann"], &out);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("--method multiscale"), "{err}");
    assert!(!out.exists());
}

/// The acceptance check of issue 5 as a user runs it: a flat grid through the binary with
/// default options, measured by `eval --example`, against 2D multiscale synthesis of the
/// same example at the same size. With the default handedness (`tiles`) the face maps show
/// the example as stored; `--handedness outside` mirrors them (the surface seen from
/// outside shows the example), which the tile-based patch fidelity sees as worse.
#[test]
fn flat_grid_through_the_cli_matches_2d_patch_fidelity_with_default_handedness() {
    let dir = tempfile::tempdir().unwrap();
    let k = 6usize;
    let n = 24usize;
    let mesh = dir.path().join("flat.obj");
    std::fs::write(&mesh, grid_obj(k, 0.0)).unwrap();
    let example_path = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/gravel.png");
    let example = surfsynth::example::Example::load(example_path).unwrap();
    let pf = |method: &str, handedness: &str| {
        let out = dir.path().join(format!("{method}-{handedness}"));
        let o = Command::new(env!("CARGO_BIN_EXE_surfsynth"))
            .arg("synth")
            .arg("--mesh")
            .arg(&mesh)
            .args(["--example", example_path, "--method", method])
            .args(["--handedness", handedness, "--resolution", &n.to_string()])
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let opts = surfsynth::eval::EvalOptions {
            example: Some(example_path.into()),
            ..Default::default()
        };
        let q = surfsynth::eval::evaluate_with(&out, &opts).unwrap();
        assert_eq!(q.coverage, 1.0);
        q.patch_fidelity.unwrap()
    };
    // 2D reference: the same evaluator on one (k·n)² domain.
    let mut p2 = surfsynth::synth::synth2d::Params2d::new(k * n, k * n);
    p2.seed = 1;
    let img = surfsynth::pyramid::Image::from_example(&example);
    let o = surfsynth::synth::synth2d::synthesize(&img, &p2).unwrap();
    let pf2 = surfsynth::eval::image_patch_fidelity(&o.image, &example).unwrap();
    for method in ["multiscale", "coherent"] {
        let tiles = pf(method, "tiles");
        let outside = pf(method, "outside");
        eprintln!("{method}: patch fidelity tiles {tiles:.3}, outside {outside:.3}, 2D {pf2:.3}");
        // Issue 5's bar (1.1x). Measured 0.282 vs 2D 0.273 (1.2-1.35x before the coarsest
        // level's fetch rule was fixed; docs/multiscale.md, "Small domains").
        if method == "multiscale" {
            assert!(tiles <= 1.1 * pf2, "{method}: {tiles:.3} vs 2D {pf2:.3}");
        }
        // gravel is lit from one side: its mirror image matches clearly worse.
        assert!(
            outside > 1.15 * tiles,
            "{method}: mirrored {outside:.3} vs {tiles:.3}"
        );
    }
}

#[test]
fn bench_multiscale_reports_both_searches() {
    let o = Command::new(env!("CARGO_BIN_EXE_surfsynth"))
        .args(["bench", "multiscale", "--domains", "8", "--resolution", "8"])
        .args(["--example-size", "32"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let rows: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let rows = rows.as_array().unwrap();
    assert_eq!(rows.len(), 2);
    for (row, search) in rows.iter().zip(["kcoherence", "ann"]) {
        assert_eq!(row["search"], search);
        assert_eq!(row["example"], serde_json::json!([32, 32]));
        let faces = row["faces"].as_u64().unwrap();
        assert!(faces >= 8);
        assert_eq!(row["texels"].as_u64().unwrap(), faces * 64);
        assert!(row["total_seconds"].as_f64().unwrap() > 0.0);
    }
    // An example that cannot give the requested size is a clear error.
    let o = Command::new(env!("CARGO_BIN_EXE_surfsynth"))
        .args(["bench", "multiscale", "--example-size", "192"])
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("192x192"));
}
