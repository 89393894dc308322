//! Rate of the patterns that chart sampling marches (near extraordinary vertices), and a
//! dump of their samples so that a change in evaluation can be checked bit-for-bit.
//! `cargo test --release --test march_bench -- --ignored --nocapture`
//! (MB_MESH=spot|dt|tri|bunny, MB_K=5|9, MB_N=patterns, MB_DUMP=path, MB_REPS=n; unset or
//! unparsable values take the defaults: Spot, 9, 300, no dump, 1).
mod common;

use common::{data, env_or};
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicIsize, Ordering};
use subdiv::{DomainId, DomainLocation, Surface};

/// Live heap bytes (to measure the surface and the per-thread deep cache).
struct Counting;
static LIVE: AtomicIsize = AtomicIsize::new(0);
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        LIVE.fetch_add(l.size() as isize, Ordering::Relaxed);
        System.alloc(l)
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        LIVE.fetch_sub(l.size() as isize, Ordering::Relaxed);
        System.dealloc(p, l)
    }
}
#[global_allocator]
static A: Counting = Counting;
fn live() -> f64 {
    LIVE.load(Ordering::Relaxed) as f64 / 1e6
}
use surfsynth::field::{Orientation, OrientationField};
use surfsynth::sampling::{Method, Sampler, SamplerKind};

#[inline(never)]
fn march_loop(
    sam: &Sampler,
    cs: &[DomainLocation],
    delta: f64,
    k: usize,
    out: &mut Vec<Option<DomainLocation>>,
) {
    for c in cs {
        let i = out.len() - k * k;
        sam.sample(*c, delta, k, SamplerKind::Chart, &mut out[i..]);
        out.extend(std::iter::repeat_n(None, k * k));
    }
}

#[test]
#[ignore]
fn march_bench() {
    let rel = match std::env::var("MB_MESH").as_deref() {
        Ok("dt") => "meshes/double_torus_genus2.obj",
        Ok("tri") => "meshes/spot_triangulated.obj",
        Ok("bunny") => "meshes/stanford_bunny.obj",
        _ => "opensubdiv-reference/spot_control_mesh.obj",
    };
    let (k, reps, npat) = (
        env_or("MB_K", 9usize),
        env_or("MB_REPS", 1usize),
        env_or("MB_N", 300usize),
    );
    let h0 = live();
    let s = Surface::load_obj(data(rel)).unwrap();
    println!("surface: {:.3} MB live heap", live() - h0);
    let f = OrientationField::compute(&s, &Orientation::Auto).unwrap();
    let n = 32;
    let delta = surfsynth::sampling::median_texel_spacing(&s, n);
    let total = s.num_domains() * n * n;
    let sam = Sampler::new(&s, &f);
    let mut buf = vec![None; k * k];
    // Centres like the bench's, kept where chart sampling marches.
    let mut cs = Vec::new();
    for i in 0..40000usize {
        let t = (i * 7919 + 13) % total;
        let (d, r) = (t / (n * n), t % (n * n));
        let c = DomainLocation {
            domain: DomainId::from_idx(d),
            u: ((r % n) as f64 + 0.5) / n as f64,
            v: ((r / n) as f64 + 0.5) / n as f64,
        };
        if sam.sample(c, delta, k, SamplerKind::Chart, &mut buf).method == Method::March {
            cs.push(c);
            if cs.len() == npat {
                break;
            }
        }
    }
    println!(
        "live heap after choosing the centres (surface, field, sampler, marching mesh, deep cache): {:.3} MB",
        live()
    );
    let mut out: Vec<Option<DomainLocation>> = Vec::new();
    for _ in 0..reps {
        drop(out);
        out = Vec::with_capacity(k * k * (cs.len() + 1));
        out.resize(k * k, None);
        let h1 = live();
        let t0 = std::time::Instant::now();
        march_loop(&sam, &cs, delta, k, &mut out);
        let secs = t0.elapsed().as_secs_f64();
        println!(
            "{rel} K{k}: {} marched patterns, {:.3} M samples/s; heap growth {:.3} MB",
            cs.len(),
            (cs.len() * k * k) as f64 / secs / 1e6,
            live() - h1
        );
    }
    if let Ok(p) = std::env::var("MB_DUMP") {
        let mut txt = String::new();
        for o in &out {
            match o {
                Some(l) => txt += &format!("{} {:e} {:e}\n", l.domain.0, l.u, l.v),
                None => txt += "-\n",
            }
        }
        std::fs::write(p, txt).unwrap();
    }
}
