//! Spatially varying scale ("progressively variant" textures, paper 001 §3.1): a scale map
//! gives factor 1 along the left edge of a flat 24x6 strip and 3 along the right edge; the
//! factors, interpolated over the surface, multiply the scale, so the bricks grow threefold
//! from one end to the other. Prints, per quarter of the strip, the requested local scale
//! (geometry.exr `scale`) and the measured one (surface step over source step between
//! adjacent texels of one patch).
//!
//! ```sh
//! cargo run --release --example 11_varying_scale -- out/varying-scale
//! cargo run --release -- render out/varying-scale --yaw 0 --pitch 0 --width 1600 --height 460
//! ```
//! The same from the command line: `synth --scale-map FILE` (format in docs/formats.md).
//!
//! With a second argument `orient` the scale comes instead from the lengths of the
//! directions of an orientation constraints file (`synth --orient orient.txt
//! --scale-from-orient`, docs/field.md): the example writes `inputs/orient.txt`, which pins
//! v1 along x at the same vertices with directions of length 1 and 3, and uses it for both
//! the field and the scale:
//! ```sh
//! cargo run --release --example 11_varying_scale -- out/varying-scale-orient orient
//! ```

use glam::DVec3;
use surfsynth::example::Example;
use surfsynth::field::Orientation;
use surfsynth::synthesizer::{Method, Synthesizer};

/// Running-bond bricks (as example 03), 24x10 px with 2 px mortar.
fn bricks(side: usize) -> Example {
    let rgb = (0..side * side)
        .map(|i| {
            let (x, y) = (i % side, i / side);
            let shift = if (y / 12) % 2 == 0 { 0 } else { 13 };
            if (x + shift) % 26 < 2 || y % 12 < 2 {
                [0.55, 0.53, 0.50]
            } else {
                let v = 0.05 * (((x + shift) / 26 * 7 + y / 12 * 13) % 5) as f32;
                [0.45 + v, 0.16 + v / 2.0, 0.10]
            }
        })
        .collect();
    Example::from_linear(side, side, rgb)
}

fn main() -> surfsynth::Result<()> {
    let out = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "out/varying-scale".into());
    // The strip (24x6 unit quads of side 1/4) and its scale map, written as files the
    // way `synth --mesh strip.obj --scale-map scale.txt` reads them.
    let (w, h) = (24usize, 6usize);
    let inputs = std::path::Path::new(&out).join("inputs");
    std::fs::create_dir_all(&inputs)
        .map_err(|e| surfsynth::Error::io(&inputs, "cannot create", e))?;
    let mut obj = String::new();
    for y in 0..=h {
        for x in 0..=w {
            obj += &format!("v {} {} 0\n", x as f64 / 4.0, y as f64 / 4.0);
        }
    }
    for q in 0..h * w {
        let i = q / w * (w + 1) + q % w + 1; // OBJ indices are 1-based
        obj += &format!("f {} {} {} {}\n", i, i + 1, i + w + 2, i + w + 1);
    }
    // Factor 1 at every control vertex of the left edge, 3 at the right edge (0-based).
    let mut map = String::from("# vertex INDEX FACTOR\n");
    for y in 0..=h {
        map += &format!("vertex {} 1\nvertex {} 3\n", y * (w + 1), y * (w + 1) + w);
    }
    // The same factors as the lengths of orientation pins along x (`vertex I DX DY DZ`).
    let mut pins = String::from("# vertex INDEX DX DY DZ: v1 along x, |d| the scale factor\n");
    for y in 0..=h {
        pins += &format!(
            "vertex {} 1 0 0\nvertex {} 3 0 0\n",
            y * (w + 1),
            y * (w + 1) + w
        );
    }
    let (mesh, scale, orient) = (
        inputs.join("strip.obj"),
        inputs.join("scale.txt"),
        inputs.join("orient.txt"),
    );
    for (p, text) in [(&mesh, &obj), (&scale, &map), (&orient, &pins)] {
        std::fs::write(p, text).map_err(|e| surfsynth::Error::io(p, "cannot write", e))?;
    }
    let from_orient = std::env::args().nth(2).as_deref() == Some("orient");
    let s = Synthesizer::new(&mesh, bricks(128)).method(Method::Optimise);
    let s = if from_orient {
        s.orientation(Orientation::Constraints(orient))
            .scale_from_orientation()
    } else {
        s.orientation(Orientation::Axis(DVec3::X)).scale_map(&scale)
    };
    let (r, report) = s.run_to(&out)?;

    // Per quarter of the strip (by x): median requested and measured local scale.
    let (su, sv) = (
        r.maps.channel("source.u").unwrap(),
        r.maps.channel("source.v").unwrap(),
    );
    let (g, local) = (&r.geometry, r.local_scale.as_ref().unwrap());
    let mut quarters = vec![(Vec::new(), Vec::new()); 4];
    for a in 0..g.len() {
        let b = a + 1; // the right neighbour, when in the same row of the same face
        let (d, x, _) = g.layout.coords(a);
        if x + 1 >= g.layout.dims(d).0 {
            continue;
        }
        let ds = ((su[a] - su[b]) as f64).hypot((sv[a] - sv[b]) as f64);
        if ds > 1e-6 && ds <= 4.0 {
            let q = ((g.pos[a].x as f64 / 6.0 * 4.0) as usize).min(3);
            quarters[q].0.push(0.5 * (local[a] + local[b]) as f64);
            quarters[q].1.push(g.pos[a].distance(g.pos[b]) as f64 / ds);
        }
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    for (i, (req, meas)) in quarters.iter_mut().enumerate() {
        let (a, b) = (median(req), median(meas));
        println!(
            "quarter {i}: requested {a:.5} (factor {:.2}), measured {b:.5} ({:+.1}%)",
            a / report.scale,
            (b / a - 1.0) * 100.0
        );
    }
    println!("wrote {out} (scale map: {:?})", report.scale_map);
    Ok(())
}
