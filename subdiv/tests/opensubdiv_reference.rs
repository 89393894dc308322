//! Our subdivision against OpenSubdiv 3.6.0 (`shared/data/opensubdiv-reference/`):
//! refined vertices (levels 1-3, as point sets), limit positions and normals on the 5x5
//! grid per domain, and at 8x8 texel centres through the same call `bake` makes.

use glam::DVec3;
use std::path::PathBuf;
use subdiv::refine::refine;
use subdiv::{ControlMesh, DomainId, LimitSample, Surface};

fn reference_dir() -> PathBuf {
    let shared = std::env::var_os("SURFSYNTH_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared"));
    let dir = shared.join("data/opensubdiv-reference");
    assert!(
        dir.is_dir(),
        "reference data not found at {} (set SURFSYNTH_SHARED)",
        dir.display()
    );
    dir
}

const SHAPES: &[&str] = &[
    "catmark_cube",
    "cube",
    "grid4x4",
    "catmark_edgecorner",
    "catmark_nonquads",
    "catmark_pole8",
    "catmark_torus",
    "spot_control_mesh",
    "blub_control_mesh",
];

struct Row {
    face: u32,
    a: f64,
    b: f64,
    p: DVec3,
    n: DVec3,
    flag: bool,
}

fn read_csv(name: &str) -> Option<Vec<Row>> {
    let text = std::fs::read_to_string(reference_dir().join(name)).ok()?;
    let mut rows = Vec::new();
    for line in text.lines().skip(1) {
        let c: Vec<f64> = line.split(',').map(|x| x.parse().unwrap()).collect();
        rows.push(Row {
            face: c[0] as u32,
            a: c[1],
            b: c[2],
            p: DVec3::new(c[3], c[4], c[5]),
            n: DVec3::new(c[6], c[7], c[8]),
            flag: c[11] == 1.0,
        });
    }
    Some(rows)
}

fn load(shape: &str) -> Surface {
    Surface::new(ControlMesh::load_obj(reference_dir().join(format!("{shape}.obj"))).unwrap())
}

fn diag(s: &Surface) -> f64 {
    let (lo, hi) = s.bounds();
    (hi - lo).length()
}

#[derive(Default, Debug)]
struct Errors {
    pos: f64,
    normal_deg: f64,
    flagged_normal_deg: f64,
    count: usize,
}

fn compare(shape: &str, rows: &[Row], eval: impl Fn(&Row) -> LimitSample, d: f64) -> Errors {
    let mut e = Errors::default();
    for r in rows {
        let s = eval(r);
        let pe = (s.p - r.p).length() / d;
        let ang = s.n.dot(r.n).clamp(-1.0, 1.0).acos().to_degrees();
        assert!(
            pe.is_finite() && ang.is_finite(),
            "{shape}: non-finite at face {} ({}, {})",
            r.face,
            r.a,
            r.b
        );
        e.pos = e.pos.max(pe);
        if r.flag {
            e.flagged_normal_deg = e.flagged_normal_deg.max(ang);
        } else {
            if ang > 0.01 {
                eprintln!(
                    "{shape}: face {} ({}, {}): normal off by {ang}°: ours {} ref {}",
                    r.face, r.a, r.b, s.n, r.n
                );
            }
            e.normal_deg = e.normal_deg.max(ang);
        }
        e.count += 1;
    }
    e
}

/// Loose bound for normals at boundary vertices with 3+ faces, which OpenSubdiv itself
/// says are not uniquely defined.
const FLAGGED_NORMAL_DEG: f64 = 10.0;

#[test]
fn limit_grid_matches_opensubdiv() {
    for shape in SHAPES {
        let s = load(shape);
        let rows = read_csv(&format!("{shape}.limit.csv")).unwrap();
        let e = compare(
            shape,
            &rows,
            |r| s.eval(DomainId(r.face), r.a, r.b),
            diag(&s),
        );
        eprintln!("{shape} limit: {e:?}");
        assert_eq!(s.num_domains(), rows.len() / 25, "{shape}: domain count");
        assert!(
            e.pos <= 1e-6,
            "{shape}: position error {} of the diagonal",
            e.pos
        );
        assert!(
            e.normal_deg <= 0.01,
            "{shape}: normal error {}°",
            e.normal_deg
        );
        assert!(
            e.flagged_normal_deg <= FLAGGED_NORMAL_DEG,
            "{shape}: flagged normal error {}°",
            e.flagged_normal_deg
        );
    }
}

#[test]
fn texel_centres_match_opensubdiv() {
    for shape in SHAPES {
        let s = load(shape);
        let rows = read_csv(&format!("{shape}.texels.csv")).unwrap();
        let n = 8;
        let mut maps = vec![LimitSample::default(); s.num_domains() * n * n];
        for (d, chunk) in maps.chunks_mut(n * n).enumerate() {
            s.eval_texels(DomainId(d as u32), n, chunk);
        }
        let e = compare(
            shape,
            &rows,
            |r| maps[r.face as usize * n * n + r.b as usize * n + r.a as usize],
            diag(&s),
        );
        eprintln!("{shape} texels: {e:?}");
        assert!(
            e.pos <= 1e-6,
            "{shape}: position error {} of the diagonal",
            e.pos
        );
        assert!(
            e.normal_deg <= 0.01,
            "{shape}: normal error {}°",
            e.normal_deg
        );
        assert!(
            e.flagged_normal_deg <= FLAGGED_NORMAL_DEG,
            "{shape}: flagged normal error {}°",
            e.flagged_normal_deg
        );
    }
}

#[test]
fn refined_vertices_match_opensubdiv_as_point_sets() {
    let mut tested = 0;
    for shape in SHAPES {
        let Ok(text) =
            std::fs::read_to_string(reference_dir().join(format!("{shape}.refined.csv")))
        else {
            continue;
        };
        let cm = ControlMesh::load_obj(reference_dir().join(format!("{shape}.obj"))).unwrap();
        let (lo, hi) = cm.bounds();
        let d = (hi - lo).length();
        let mut levels = vec![cm.mesh.clone()];
        for _ in 0..3 {
            let next = refine(levels.last().unwrap());
            levels.push(next);
        }
        for (level, refined) in levels.iter().enumerate().skip(1) {
            let refp: Vec<DVec3> = text
                .lines()
                .skip(1)
                .filter_map(|l| {
                    let c: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
                    (c[0] as usize == level).then(|| DVec3::new(c[2], c[3], c[4]))
                })
                .collect();
            let ours = &refined.positions;
            assert_eq!(
                ours.len(),
                refp.len(),
                "{shape} level {level}: vertex count"
            );
            // Same order as OpenSubdiv (vertex, face, edge points) for vertex and face
            // points; edges may be numbered differently, so match edge points as a set.
            let mut worst: f64 = 0.0;
            for p in &refp {
                let best = ours
                    .iter()
                    .map(|q| (*q - *p).length())
                    .fold(f64::INFINITY, f64::min);
                worst = worst.max(best / d);
            }
            for q in ours {
                let best = refp
                    .iter()
                    .map(|p| (*q - *p).length())
                    .fold(f64::INFINITY, f64::min);
                worst = worst.max(best / d);
            }
            assert!(
                worst <= 1e-12,
                "{shape} level {level}: point-set distance {worst}"
            );
            tested += 1;
        }
    }
    assert!(tested >= 18, "refined references found: {tested}");
}
