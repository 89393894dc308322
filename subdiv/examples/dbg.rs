use glam::DVec3;
use subdiv::*;
fn main() {
    let shape = std::env::args().nth(1).unwrap();
    let dir = "/work/shared/data/opensubdiv-reference";
    let s = Surface::new(ControlMesh::load_obj(format!("{dir}/{shape}.obj")).unwrap());
    let text = std::fs::read_to_string(format!("{dir}/{shape}.limit.csv")).unwrap();
    let mut worst = std::collections::BTreeMap::new();
    for l in text.lines().skip(1) {
        let c: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
        let r = s.eval(DomainId(c[0] as u32), c[1], c[2]);
        let e = (r.p - DVec3::new(c[3], c[4], c[5])).length();
        let w = worst.entry(c[0] as u32).or_insert((0.0f64, 0.0, 0.0));
        if e > w.0 {
            *w = (e, c[1], c[2]);
        }
    }
    for (f, w) in worst {
        if w.0 > 1e-9 {
            let face = subdiv::FaceId(f);
            let vs = s.control.mesh.face_vertices(face);
            let info: Vec<String> = vs
                .iter()
                .map(|&v| {
                    format!(
                        "{}:{}f{}",
                        v,
                        s.control.mesh.vertex_faces(VertexId(v)),
                        if s.control.mesh.is_boundary_vertex(VertexId(v)) {
                            "b"
                        } else {
                            ""
                        }
                    )
                })
                .collect();
            println!(
                "face {f} err {:.3e} at ({},{}) verts {:?}",
                w.0, w.1, w.2, info
            );
        }
    }
}
