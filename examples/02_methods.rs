//! Every synthesis method on the same mesh and example, side by side: structure (patch
//! fidelity pf4/pf8, BRIEF), seams, stretch and time — the trade-off docs/synthesis.md
//! tabulates.
//!
//! ```sh
//! cargo run --release --example 02_methods
//! ```
//!
//! `Method::DEFAULT` (texture optimisation) keeps structure best; `Coherent` is the fast
//! preview; `Patches` is nearly as good as the default and faster; `Multiscale` is the
//! per-texel method of Ying et al. 2001 §4.

use surfsynth::eval::{evaluate_maps, patch_fidelities};
use surfsynth::synthesizer::{Method, Synthesizer};

fn main() -> surfsynth::Result<()> {
    let fixtures = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures");
    let mesh = format!("{fixtures}/spot_control_mesh.obj");
    let example = surfsynth::example::Example::load(format!("{fixtures}/gravel.png"))?;
    println!("method       pf4    pf8    seam   stretch p10-p90   seconds");
    for method in Method::ALL {
        let r = Synthesizer::new(mesh.as_str(), example.clone())
            .method(method)
            .resolution(16)
            .seed(1)
            .run()?;
        let geometry = r.geometry_maps();
        let scale = Some(r.report.scale);
        let q =
            evaluate_maps(&r.maps, &geometry, scale, None).map_err(surfsynth::Error::invalid)?;
        let pf = patch_fidelities(&r.maps, &geometry, &r.example, scale);
        let s = q.scale_fidelity.expect("coherent pairs");
        println!(
            "{:<12} {:.3}  {:.3}  {:.3}  {:.3}-{:.3}       {:.2}",
            method.name(),
            pf.pf4.unwrap_or(f64::NAN),
            pf.pf8.unwrap_or(f64::NAN),
            q.seam_ratio.unwrap_or(f64::NAN),
            s.p10,
            s.p90,
            r.report.seconds.synthesis
        );
    }
    Ok(())
}
