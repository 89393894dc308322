use std::time::Instant;
use subdiv::*;
fn main() {
    let path = std::env::args().nth(1).unwrap();
    let n: usize = std::env::args().nth(2).unwrap().parse().unwrap();
    let t0 = Instant::now();
    let mut cm = ControlMesh::load_obj(&path).unwrap();
    let levels: usize = std::env::args()
        .nth(3)
        .map(|s| s.parse().unwrap())
        .unwrap_or(0);
    for _ in 0..levels {
        let r = subdiv::refine::refine(&cm.mesh);
        cm = ControlMesh::from_polygons(
            r.positions.clone(),
            r.face_starts().to_vec(),
            r.half_edge_vertices().to_vec(),
        )
        .unwrap();
    }
    let t1 = Instant::now();
    let s = Surface::new(cm);
    let t2 = Instant::now();
    let mut buf = vec![LimitSample::default(); n * n];
    let mut acc = 0.0;
    for d in 0..s.num_domains() {
        s.eval_texels(DomainId(d as u32), n, &mut buf);
        acc += buf[0].p.x;
    }
    let t3 = Instant::now();
    let texels = s.num_domains() * n * n;
    println!(
        "domains {} texels {} load {:?} build {:?} eval {:?} => {:.2} M texels/s/core ({acc})",
        s.num_domains(),
        texels,
        t1 - t0,
        t2 - t1,
        t3 - t2,
        texels as f64 / (t3 - t2).as_secs_f64() / 1e6
    );
}
