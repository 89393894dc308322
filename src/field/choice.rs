//! Fields chosen per mesh: `--orient straight` (the straightest of a few candidate fields)
//! and `upright` (`up`, unless the surface is mostly level; [`upright`]).
//!
//! # Why choose at all
//! The smoothest field (Knöppel et al. 2013, `--orient auto`, [`Orientation::Auto`]) minimises the *squared*
//! turning Σ (θ_i − θ_j transported)², which spreads the turning the surface's curvature and
//! topology force over the whole surface: on Spot, rows of bricks arc over every flank. A
//! structured example does not mind a few regions of strong turning (near singularities,
//! where any field breaks the rows) as much as moderate turning everywhere, because BRIEF's
//! structure measure (pf8, and the eye) compares windows of about 56 example pixels with
//! straight pieces of the example. Measured at N = 32 with the 256² brick crop (pf8, lower
//! is better; docs/field.md has the full table):
//!
//! | mesh | smooth | +x | +y | +z |
//! |---|---|---|---|---|
//! | Spot | 0.114 | 0.112 | **0.097** | 0.113 |
//! | double torus | 0.126 | **0.112** | 0.115 | 0.127 |
//! | open cube | 0.102 | 0.079 | **0.075** | 0.094 |
//! | blub | 0.140 | 0.135 | 0.125 | **0.118** |
//! | bunny (N = 8) | **0.080** | 0.094 | 0.084 | 0.095 |
//!
//! No one candidate wins everywhere, so `straight` computes them all on a coarse level and keeps
//! the one whose frame turns fast over the least area.
//!
//! # The score
//! For vertices spread evenly over the coarse limit mesh, the gradient g of the field angle
//! is fitted by least squares over a disc of radius ℓ (the structure length: half of pf8's
//! window, 28 example pixels) from every neighbour's v1 projected on the vertex's tangent
//! plane. The score is the fraction of those vertices where |g| ℓ > [`TURN`]: where the
//! frame turns by more than about 6° over half a window, a straight row of the example can
//! no longer follow it. A disc, not the mesh's edges: per-edge differences at fine levels see
//! the solver's residual wiggles, not the turning at the scale of the structure.
//!
//! Ties (a flat grid, where every candidate is parallel) go to the earlier candidate, so a
//! flat mesh keeps the smooth field (exactly +x in the xy plane).

use super::{FieldOptions, Orientation, OrientationField};
use glam::DVec3;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rayon::prelude::*;
use subdiv::Surface;

/// Turning (radians over the structure length) above which a vertex counts as bent.
pub const TURN: f64 = 0.1;
/// The coarse level candidates are scored on (or the field's own level when lower).
pub const SCORE_LEVEL: u32 = 2;
/// Vertices scored per candidate (at most; evenly spread by index).
const SAMPLES: usize = 4000;
/// Neighbours whose normal is more than 60° from the vertex's belong to another sheet.
const SAME_SHEET_COS: f64 = 0.5;

/// The candidates in tie-breaking order.
pub fn candidates() -> [Orientation; 4] {
    [
        Orientation::Auto,
        Orientation::Axis(DVec3::X),
        Orientation::Axis(DVec3::Y),
        Orientation::Axis(DVec3::Z),
    ]
}

/// What a chosen orientation (`straight`, `upright`) chose and why (for report.json).
#[derive(Clone, Debug, PartialEq)]
pub struct Choice {
    /// Label of the winner: `auto` (the smooth field), `+x`, `+y`, `+z` or `up`.
    pub chosen: String,
    /// What decided.
    pub why: Why,
}

/// The measure behind a [`Choice`].
#[derive(Clone, Debug, PartialEq)]
pub enum Why {
    /// `straight`: every candidate's bent fraction (0..1, in candidate order), measured
    /// over the structure length ℓ.
    Straightest {
        scores: Vec<(String, f64)>,
        length: f64,
    },
    /// `upright`: the share of the surface's area that is level against the axis
    /// (normal within `LEVEL_ANGLE_DEG` of it).
    Level { fraction: f64 },
}

/// Fraction of (sampled) vertices of `field`'s limit mesh where the field turns by more
/// than `TURN` over `length` (module doc).
pub fn bent_fraction(field: &OrientationField, length: f64) -> f64 {
    let lm = field.limit_mesh();
    let v1 = field.vertex_v1();
    let pts: Vec<[f64; 3]> = lm.position.iter().map(|p| p.to_array()).collect();
    let Ok(tree) = ImmutableKdTree::<f64, 3>::new_from_slice(&pts) else {
        return 0.0;
    };
    let step = pts.len().div_ceil(SAMPLES).max(1);
    let samples: Vec<usize> = (0..pts.len()).step_by(step).collect();
    let bent: Vec<Option<bool>> = samples
        .par_iter()
        .map(|&i| {
            let (x, n, u) = (lm.position[i], lm.normal[i], v1[i]);
            let w = n.cross(u);
            let hits = tree
                .query(&pts[i])
                .within::<SquaredEuclidean<f64>>(length * length)
                .unsorted()
                .execute();
            // Normal equations of angle(j) ≈ g · (offset of j in (u, w)).
            let (mut a11, mut a12, mut a22, mut b1, mut b2) = (0.0f64, 0.0, 0.0, 0.0, 0.0);
            for h in hits {
                let j = h.item as usize;
                if j == i || lm.normal[j].dot(n) < SAME_SHEET_COS {
                    continue;
                }
                let t = v1[j] - n * n.dot(v1[j]);
                let angle = w.dot(t).atan2(u.dot(t));
                let d = lm.position[j] - x;
                let (p, q) = (d.dot(u), d.dot(w));
                a11 += p * p;
                a12 += p * q;
                a22 += q * q;
                b1 += p * angle;
                b2 += q * angle;
            }
            let det = a11 * a22 - a12 * a12;
            if !det.is_finite() || det.abs() <= 1e-300 {
                return None;
            }
            let g1 = (a22 * b1 - a12 * b2) / det;
            let g2 = (a11 * b2 - a12 * b1) / det;
            Some(g1.hypot(g2) * length > TURN)
        })
        .collect();
    let (mut hit, mut total) = (0usize, 0usize);
    for b in bent.into_iter().flatten() {
        total += 1;
        hit += b as usize;
    }
    if total == 0 {
        0.0
    } else {
        hit as f64 / total as f64
    }
}

/// Scores every candidate on the coarse level and returns the winner's orientation with
/// the [`Choice`], plus the winner's field when the coarse level is the final one (so it
/// is not computed twice).
pub fn straightest(
    surface: &Surface,
    opts: &FieldOptions,
    final_level: u32,
    length: f64,
) -> anyhow::Result<(Orientation, Choice, Option<OrientationField>)> {
    let level = SCORE_LEVEL.min(final_level);
    let coarse = FieldOptions {
        level: Some(level),
        ..opts.clone()
    };
    let mut best: Option<(usize, f64, OrientationField)> = None;
    let mut scores = Vec::new();
    for (k, o) in candidates().iter().enumerate() {
        let f = OrientationField::compute_fixed(surface, o, &coarse)?;
        let s = bent_fraction(&f, length);
        scores.push((o.label(), s));
        if best.as_ref().is_none_or(|b| s < b.1) {
            best = Some((k, s, f));
        }
    }
    let (k, _, field) = best.expect("at least one candidate");
    let chosen = candidates()[k].clone();
    let choice = Choice {
        chosen: chosen.label(),
        why: Why::Straightest { scores, length },
    };
    Ok((chosen, choice, (level == final_level).then_some(field)))
}

/// A surface normal within this angle of `upright`'s axis counts as level.
pub const LEVEL_ANGLE_DEG: f64 = 30.0;

/// `upright` keeps `up` while at most this share of the surface's area is level.
pub const LEVEL_SHARE_MAX: f64 = 0.5;

/// Share of the surface's area whose normal lies within `LEVEL_ANGLE_DEG` of `axis` (either
/// way: floors and ceilings), on the limit mesh of `level`: each face weighs its area,
/// level when the mean of its corners' limit normals is.
pub fn level_fraction(surface: &Surface, axis: DVec3, level: u32) -> f64 {
    let lm = surface.limit_mesh(level.max(1));
    let a = axis.normalize_or_zero();
    let cos = LEVEL_ANGLE_DEG.to_radians().cos();
    let (level_area, total) = (0..lm.mesh.num_faces())
        .into_par_iter()
        .map(|f| {
            let vs = lm.mesh.face_vertices(subdiv::FaceId::from_idx(f));
            let (mut area, mut n) = (DVec3::ZERO, DVec3::ZERO);
            for (k, &v) in vs.iter().enumerate() {
                let w = vs[(k + 1) % vs.len()];
                area += lm.position[v as usize].cross(lm.position[w as usize]);
                n += lm.normal[v as usize];
            }
            let area = 0.5 * area.length();
            let level = n.normalize_or_zero().dot(a).abs() > cos;
            (if level { area } else { 0.0 }, area)
        })
        .reduce(|| (0.0, 0.0), |x, y| (x.0 + y.0, x.1 + y.1));
    if total > 0.0 {
        level_area / total
    } else {
        0.0
    }
}

/// `upright`: `up` along `axis` where the surface has an up, else the smooth field.
///
/// # Why
/// `up` keeps the example's up along the axis projected on the tangent planes: a brick
/// wall's courses stay level on a cow's flanks, and pf8 there is the best of every field
/// measured (docs/field.md). But on a surface that is mostly level — terrain, a floor, a
/// shallow dome, a cloth lying flat — the projected axis is short and points uphill, so
/// `up` draws the example in contour rings around every summit. Measured (optimise, N = 32,
/// seed 1, pf8 `up` → `auto`): a bumpy terrain bricks 0.108 → 0.037, the lattice weave
/// 0.330 → 0.037, reptile scales 0.235 → 0.106; a shallow hexagon dome bricks 0.057 →
/// 0.026, the weave 0.246 → 0.022 (seed 2); both are 100% level. On every other mesh
/// measured at most a third of the area is level (Spot 14%, Blub 14%, the double torus
/// 12%, a sphere 14%, the bunny 18%, the open cube 18%, a bumpy torus lying flat 25%, the
/// closed cube 32%, a torus lying flat 33%) and `up` stays: there it wins or ties (Spot
/// bricks 0.096 against 0.112, the closed cube 0.077 against 0.113, a sphere 0.055 against
/// 0.093; the tori within ±0.015 with bricks). Threshold: [`LEVEL_SHARE_MAX`] of the area
/// within [`LEVEL_ANGLE_DEG`].
/// (The bent fraction `straight` scores by did not separate these cases: it prefers the
/// smooth field on the sphere, where `up` is far better.)
pub fn upright(surface: &Surface, axis: DVec3, level: u32) -> (Orientation, Choice) {
    let fraction = level_fraction(surface, axis, level);
    let chosen = if fraction > LEVEL_SHARE_MAX {
        Orientation::Auto
    } else {
        Orientation::Up(axis)
    };
    let choice = Choice {
        chosen: chosen.label(),
        why: Why::Level { fraction },
    };
    (chosen, choice)
}

#[cfg(test)]
mod tests {
    use super::*;
    use subdiv::ControlMesh;

    fn grid(k: usize, bump: f64) -> Surface {
        let mut p = Vec::new();
        for j in 0..=k {
            for i in 0..=k {
                let (x, y) = (i as f64 / k as f64, j as f64 / k as f64);
                let z = bump * (std::f64::consts::PI * x).sin() * (std::f64::consts::PI * y).sin();
                p.push(DVec3::new(x, y, z));
            }
        }
        let mut f = Vec::new();
        for j in 0..k {
            for i in 0..k {
                let a = (j * (k + 1) + i) as u32;
                let k = k as u32;
                f.push(vec![a, a + 1, a + k + 2, a + k + 1]);
            }
        }
        let f: Vec<&[u32]> = f.iter().map(|v| v.as_slice()).collect();
        Surface::new(ControlMesh::from_faces(p, &f).unwrap())
    }

    #[test]
    fn a_flat_grid_is_straight_for_every_candidate_and_keeps_the_smooth_field() {
        let s = grid(6, 0.0);
        let (o, c, _) = straightest(&s, &FieldOptions::default(), 3, 0.2).unwrap();
        assert_eq!(o, Orientation::Auto, "{c:?}");
        let Why::Straightest { scores, .. } = &c.why else {
            panic!("{c:?}")
        };
        assert!(scores.iter().all(|(_, v)| *v < 1e-9), "{c:?}");
    }

    #[test]
    fn a_field_that_swirls_scores_worse_than_a_straight_one() {
        // On a bump, the smooth field and the +x field are nearly straight; a field
        // pulled toward +z (normal in the middle) turns fast around the top.
        let s = grid(8, 0.5);
        let opts = FieldOptions {
            level: Some(2),
            ..Default::default()
        };
        let x = OrientationField::compute_with(&s, &Orientation::Axis(DVec3::X), &opts).unwrap();
        let z = OrientationField::compute_with(&s, &Orientation::Axis(DVec3::Z), &opts).unwrap();
        let (bx, bz) = (bent_fraction(&x, 0.25), bent_fraction(&z, 0.25));
        assert!(bz > bx + 0.1, "+z {bz} vs +x {bx}");
    }

    #[test]
    fn the_open_cube_chooses_the_axis_that_wraps_its_sides() {
        // Measured: the +y field (around the four sides, singular only at the top) keeps
        // rows straightest on the open cube, and gives pf8 0.075 against 0.102 smooth.
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../shared/data/meshes/cube_no_bottom.obj"
        );
        let Ok(control) = ControlMesh::load_obj(std::path::Path::new(path)) else {
            eprintln!("skipped: {path} not found (../shared beside the project)");
            return;
        };
        let s = Surface::new(control);
        let (o, c, _) = straightest(&s, &FieldOptions::default(), 4, 28.0 * 0.0116).unwrap();
        assert_eq!(o, Orientation::Axis(DVec3::Y), "{c:?}");
    }

    #[test]
    fn upright_lies_flat_on_a_level_surface_and_stands_up_on_walls() {
        // A gentle bump lying level (its normal within 30° of +z everywhere): the smooth
        // field. The same grid stood up (its normal across +y): `up`.
        let s = grid(6, 0.2);
        let (o, c) = upright(&s, DVec3::Z, 2);
        assert_eq!(o, Orientation::Auto, "{c:?}");
        let Why::Level { fraction } = c.why else {
            panic!("{c:?}")
        };
        assert!(fraction > 0.99, "{fraction}");
        let (o, c) = upright(&s, DVec3::Y, 2);
        assert_eq!(o, Orientation::Up(DVec3::Y), "{c:?}");
        assert!(
            matches!(c.why, Why::Level { fraction } if fraction < 0.01),
            "{c:?}"
        );
    }

    #[test]
    fn a_level_fraction_is_a_share_of_the_area() {
        // The limit surface of a six-quad cube is nearly round: its two caps within 30°
        // of ±y hold about a sphere's share of the area, 1 − cos 30° = 0.134 (measured
        // 0.143), whichever way the axis points; a flat level grid is all level.
        let s = Surface::new(ControlMesh::cuboid(DVec3::ZERO, DVec3::ONE));
        let sphere = 1.0 - LEVEL_ANGLE_DEG.to_radians().cos();
        for axis in [DVec3::Y, DVec3::NEG_Y, DVec3::X] {
            let f = level_fraction(&s, axis, 3);
            assert!((f - sphere).abs() < 0.02, "{axis}: {f}");
        }
        assert!((level_fraction(&grid(4, 0.0), DVec3::NEG_Z, 2) - 1.0).abs() < 1e-12);
    }
}
