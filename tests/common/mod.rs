//! Helpers shared by the root crate's integration tests: each test file says `mod common;`.
//! Cargo compiles `tests/common/mod.rs` into every test that names it and does not build it
//! as a test binary of its own. Not every test uses every helper, so each item allows
//! `dead_code` rather than the test binaries that leave it unused.

pub mod glb;
pub mod gltf_validator;

use glam::DVec3;
use std::path::PathBuf;
use subdiv::{DomainId, DomainLocation, Surface};

/// The shared data checkout (meshes, textures, OpenSubdiv reference values), which is not
/// part of this repository: `$SURFSYNTH_SHARED` when set, else `../shared` relative to
/// this crate, i.e. a `shared` directory beside the workspace checkout.
#[allow(dead_code)]
pub fn shared() -> PathBuf {
    std::env::var_os("SURFSYNTH_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared"))
}

/// `data/<rel>` in the shared checkout.
#[allow(dead_code)]
pub fn data(rel: &str) -> PathBuf {
    shared().join("data").join(rel)
}

/// The limit surface of `data/<rel>` in the shared checkout; panics when it does not load.
#[allow(dead_code)]
pub fn load(rel: &str) -> Surface {
    Surface::load_obj(data(rel)).unwrap()
}

/// A shared texture halved until its width is below `2 * size`, cropped to a square of at
/// most `size` pixels (small examples keep tests short).
#[allow(dead_code)]
pub fn texture(name: &str, size: usize) -> surfsynth::example::Example {
    use surfsynth::example::Example;
    use surfsynth::pyramid::Image;
    let ex = Example::load(data(&format!("textures/{name}"))).unwrap();
    let mut img = Image::from_example(&ex);
    while img.width >= 2 * size {
        img = img.downsample();
    }
    let size = size.min(img.width).min(img.height);
    let rgb = (0..size * size)
        .map(|i| {
            let p = img.pixel(i % size, i / size);
            [p[0], p[1], p[2]]
        })
        .collect();
    Example::from_linear(size, size, rgb)
}

/// The environment variable `name` parsed as a `T`, or `default` when it is unset or does
/// not parse (the settings of the ignored measurement tests).
#[allow(dead_code)]
pub fn env_or<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// A seeded linear congruential generator (Knuth's MMIX constants), so that random test
/// points are the same on every run and machine without a `rand` dependency.
#[allow(dead_code)]
pub struct Lcg(pub u64);

#[allow(dead_code)]
impl Lcg {
    /// The next number, uniform in [0, 1) (the top 53 bits of the state).
    pub fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// The limit position at a sampled location, `None` where the sampler found none.
#[allow(dead_code)]
pub fn pos(s: &Surface, l: &Option<DomainLocation>) -> Option<DVec3> {
    l.map(|l| s.eval(l.domain, l.u, l.v).p)
}

/// Sample centres on `s`: `n` random points (`Lcg(seed)`), then every domain corner (all
/// extraordinary vertices are domain corners).
#[allow(dead_code)]
pub fn centres(s: &Surface, n: usize, seed: u64) -> Vec<DomainLocation> {
    let mut r = Lcg(seed);
    let mut c = Vec::new();
    for _ in 0..n {
        let d = DomainId((r.next() * s.num_domains() as f64) as u32);
        c.push(DomainLocation {
            domain: d,
            u: r.next(),
            v: r.next(),
        });
    }
    for d in 0..s.num_domains() {
        for (u, v) in [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)] {
            c.push(DomainLocation {
                domain: DomainId(d as u32),
                u,
                v,
            });
        }
    }
    c
}

/// Worst |distance/δ − 1| over the adjacent pairs (along rows and columns) of a K×K grid of
/// positions (row by row, `None` where missing), the number of pairs measured and how many
/// of them are more than 5% off.
#[allow(dead_code)]
pub fn spacing(p: &[Option<DVec3>], k: usize, delta: f64) -> (f64, usize, usize) {
    let (mut w, mut n, mut over) = (0.0f64, 0, 0);
    for m in 0..k {
        for l in 0..k {
            let i = m * k + l;
            let Some(a) = p[i] else { continue };
            for j in [(l + 1 < k).then_some(i + 1), (m + 1 < k).then_some(i + k)]
                .into_iter()
                .flatten()
            {
                if let Some(b) = p[j] {
                    let e = ((b - a).length() / delta - 1.0).abs();
                    w = w.max(e);
                    n += 1;
                    over += (e > 0.05) as usize;
                }
            }
        }
    }
    (w, n, over)
}

/// One in-memory analysis store for the whole test binary: runs with the same example
/// (and parameters) share its appearance space, jump maps, k-coherence lists and multiscale
/// models instead of rebuilding them per run, and nothing touches the user's cache folder.
/// Results are bit-identical with or without it (tests/jump.rs and tests/session.rs check
/// cache hits against fresh analyses).
#[allow(dead_code)]
pub fn analyses() -> std::sync::Arc<surfsynth::synth::Analyses> {
    use std::sync::{Arc, OnceLock};
    use surfsynth::synth::Analyses;
    use surfsynth::synthesizer::CacheDir;
    static STORE: OnceLock<Arc<Analyses>> = OnceLock::new();
    STORE
        .get_or_init(|| Arc::new(Analyses::new(&CacheDir::Off)))
        .clone()
}
