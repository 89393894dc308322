use std::time::Instant;
use subdiv::*;
fn main() {
    let path = std::env::args().nth(1).unwrap();
    let t0 = Instant::now();
    let s = Surface::load_obj(&path).unwrap();
    let t1 = Instant::now();
    let lm = s.limit_mesh(3);
    let t2 = Instant::now();
    println!(
        "build {:?} limit_mesh(3) {:?} ({} verts)",
        t1 - t0,
        t2 - t1,
        lm.position.len()
    );
}
