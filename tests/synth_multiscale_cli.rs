//! `surfsynth synth --method multiscale` end to end through the binary: full coverage, the
//! method recorded in report.json, seams no worse than the acceptance bound of issue 5.

use std::process::Command;

#[test]
fn multiscale_runs_from_the_cli() {
    let dir = tempfile::tempdir().unwrap();
    // A 4x4 grid of unit quads, slightly bent so it is not flat.
    let mut obj = String::new();
    for y in 0..=4 {
        for x in 0..=4 {
            let z = 0.1 * ((x as f64) * 0.7).sin() * ((y as f64) * 0.5).cos();
            obj += &format!("v {x} {y} {z}\n");
        }
    }
    for y in 0..4 {
        for x in 0..4 {
            let i = y * 5 + x + 1;
            obj += &format!("f {} {} {} {}\n", i, i + 1, i + 6, i + 5);
        }
    }
    let mesh = dir.path().join("grid.obj");
    std::fs::write(&mesh, obj).unwrap();
    let out = dir.path().join("out");
    let example = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/gravel.png");
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
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["method"], "multiscale");
    assert!(report["multiscale"].is_object());
    let q = surfsynth::eval::evaluate(&out, None).unwrap();
    assert_eq!(q.coverage, 1.0);
    let seam = q.seam_ratio.unwrap();
    assert!(seam <= 1.15, "seam ratio {seam}");
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
