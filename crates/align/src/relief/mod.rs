//! Relief shift (issue 18). Under a flash beside the lens, a material with relief
//! (leather grain, weave, brush strokes) shows each bump's lit flank brighter, so its
//! texture appears moved on the plane towards the light's foot by a length `s(t)` that
//! depends on the light's tangent `t` there (session 12 measured 15-65 um on the hard
//! preset's leather). Glossy bumps are brightest where their normal meets the half
//! vector, which leans from the flash towards the lens, so the shift points at the foot
//! of a centre between the lens and the flash, chosen by the model
//! ([`CENTRE_WEIGHTS`]). Every flash frame shows the shift, so flash frames agree with
//! each other when their maps carry it, and the matches with the reference photo (no
//! flash) pull every map off the plane by `-s(t)`: 0.6 output px median at 4K.
//!
//! The sub-frames of the global solve can take up any smooth field per frame, so the
//! shift is invisible to it. Here a rigid model is fitted instead: one homography per
//! flash frame on lens-undistorted coordinates, one radial lens for the capture
//! (`a1`, `a2`, shared by every frame, so that no frame can bend on its own), and one
//! shift curve `s(t)` for the capture, piecewise linear over [`KNOTS`]. Marker corners
//! (flat print) carry no shift, matches with the reference photo carry their frame's,
//! matches between frames the difference of the two. The curve found then moves every
//! texture correspondence to where the plane point lies ([`correct`]), and the usual
//! solve runs again on them.

// Index loops over the small Jacobian blocks read more clearly than iterator chains.
#![allow(clippy::needless_range_loop)]

use std::collections::HashMap;

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};
use svbrdf_core::geometry::{Mat3, Vec2, Vec3};
use svbrdf_core::homography::Homography;

use crate::matching::{Matched, Registration};
use crate::solve::{project, to_params};
use crate::AlignError;

/// Light tangents at which the shift curve has a knot; `s(0) = 0`, and beyond the
/// last knot the curve stays at its last value.
pub const KNOTS: [f64; 8] = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8];
const K: usize = KNOTS.len();
/// Unknowns shared by every frame: the lens (2) and the curve.
const SHARED: usize = 2 + K;
/// The curve is applied where it lowers the rigid model's robust cost by at least this
/// share. Measured: leather 3.2-3.3% (hard-small) and 10-12% (4K), where applying it
/// lowered the error; the `paper` preset 0.3-1.0%, where applying it raised the
/// median error 0.19 -> 0.22 px; tiles 0.04-0.09% and patchwork 0.2-0.3%.
pub const MIN_GAIN: f64 = 0.02;
/// Marker corners (flat print, no shift) needed: without them a shift growing in
/// proportion to the tangent is a change of scale about each frame's light foot,
/// which each frame's own homography takes up.
pub const MIN_MARKER_CORNERS: usize = 8;
/// Texture correspondences the model uses at most (thinned evenly beyond).
const MAX_TEXTURE: usize = 60_000;
/// Where the shift may point: at the foot of `w * flash + (1 - w) * lens` for each `w`
/// here (1: the flash's foot, diffuse shading; towards the lens as specular shading of
/// the bumps weighs in). The model keeps the one with the lowest cost. On the `hard`
/// preset's 4K leather seed 2: 0.5, median error 0.282 -> 0.240 px against 1.
pub const CENTRE_WEIGHTS: [f64; 5] = [0.0, 0.25, 0.5, 0.75, 1.0];

fn one() -> f64 {
    1.0
}

/// What the relief step found (`align.json` `relief`).
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
pub struct ReliefSummary {
    /// Light tangents of the curve's knots.
    pub knots_t: Vec<f64>,
    /// Apparent shift of the texture towards the centre's foot at each knot, micrometres.
    pub shift_um: Vec<f64>,
    /// The centre the shift points at: `w * flash + (1 - w) * lens`, this `w` (one of
    /// [`CENTRE_WEIGHTS`]; records before it was chosen pointed at the flash, 1).
    #[serde(default = "one")]
    pub centre_weight: f64,
    /// Standard error of each knot's shift, micrometres.
    pub shift_um_stderr: Vec<f64>,
    /// The rigid model's lens: undistorted = distorted (1 + a1 r^2 + a2 r^4), with `r`
    /// in focal lengths.
    pub lens: [f64; 2],
    /// Flash frames in the rigid model.
    pub frames: usize,
    /// Constraints (point correspondences) in the rigid model.
    pub constraints: usize,
    /// Marker corners among them.
    pub marker_corners: usize,
    /// Robust RMS residual of the rigid model without the shift curve and with it, um.
    pub rms_um: [f64; 2],
    /// Share of the rigid model's robust cost the curve removes.
    pub gain: f64,
    /// Whether the texture correspondences were corrected and solved again.
    pub applied: bool,
    /// Why not, when not.
    pub note: Option<String>,
}

impl ReliefSummary {
    /// A doubt for `summary.warnings`: the texture moves with the flash by more than
    /// the threshold's share, and too few marker corners let it be corrected.
    pub fn doubt(&self) -> Option<String> {
        (!self.applied && self.note.is_some() && self.gain >= MIN_GAIN).then(|| {
            format!(
                "the texture appears to move with the flash (relief shading: the shift explains {:.1}% of a rigid model's residual), but the kept frames show only {} marker corners, too few to correct it; the maps may lie tens of micrometres off (about a pixel at 4K), most towards the frames' edges. Film with the markers in view more often",
                100.0 * self.gain,
                self.marker_corners
            )
        })
    }
}

impl ReliefSummary {
    /// One line for the summary.
    pub fn describe(&self) -> String {
        let peak =
            self.shift_um
                .iter()
                .copied()
                .fold(0.0f64, |a, b| if b.abs() > a.abs() { b } else { a });
        let head = format!(
            "relief shift: {} flash frames, {} marker corners",
            self.frames, self.marker_corners
        );
        match (&self.note, self.applied) {
            (Some(n), _) => format!(
                "{head}; the shift explains {:.2}% of the rigid model's residual; {n}",
                100.0 * self.gain
            ),
            (None, true) => format!(
                "{head}; texture seen up to {:.0} um towards a point {:.2} of the way from the lens to the flash (explains {:.1}% of the rigid model's residual); correspondences corrected and solved again",
                peak,
                self.centre_weight,
                100.0 * self.gain
            ),
            (None, false) => format!(
                "{head}; largest {:.0} um, explains {:.2}% of the rigid model's residual (under {:.0}%): not applied",
                peak,
                100.0 * self.gain,
                100.0 * MIN_GAIN
            ),
        }
    }
}

/// Hat-function weights of the curve's knots at tangent `t`.
fn basis(t: f64) -> [f64; K] {
    let mut b = [0.0; K];
    if t <= 0.0 {
        return b;
    }
    if t < KNOTS[0] {
        b[0] = t / KNOTS[0];
        return b;
    }
    for k in 0..K - 1 {
        if t < KNOTS[k + 1] {
            let w = (t - KNOTS[k]) / (KNOTS[k + 1] - KNOTS[k]);
            b[k] = 1.0 - w;
            b[k + 1] = w;
            return b;
        }
    }
    b[K - 1] = 1.0;
    b
}

/// Tangent of `light` at plane point `y` and the unit vector from `y` to its foot.
fn light_geometry(light: Vec3, y: Vec2) -> (f64, Vec2) {
    let d = Vec2::new(light.x - y.x, light.y - y.y);
    let rho = d.norm();
    if rho < 1e-9 || light.z <= 0.0 {
        return (0.0, Vec2::zeros());
    }
    (rho / light.z, d / rho)
}

/// The point whose foot the shift points at: `w` of the way from the lens to the flash.
fn centre(light: Vec3, lens: Vec3, w: f64) -> Vec3 {
    light * w + lens * (1.0 - w)
}

/// How the shift at `y` under `light` (or any centre) depends on each knot's value: the
/// unit vector towards its foot weighted by the knot's hat function.
fn directions(light: Vec3, y: Vec2) -> [Vec2; K] {
    let (t, u) = light_geometry(light, y);
    basis(t).map(|b| u * b)
}

/// The shift of the texture at `y` under `light` for a curve (cm on the plane).
pub(crate) fn shift_at(curve_cm: &[f64; K], light: Vec3, y: Vec2) -> Vec2 {
    directions(light, y)
        .iter()
        .zip(curve_cm)
        .map(|(d, c)| d * *c)
        .sum()
}

/// The plane point a frame's piecewise map puts pixel `p` at, with the map's 2x2
/// Jacobian (cm per pixel) there.
fn map_at(blocks: &[([f64; 4], Mat3)], p: Vec2) -> Option<(Vec2, [[f64; 2]; 2])> {
    let b = blocks
        .iter()
        .position(|(r, _)| p.x >= r[0] && p.y >= r[1] && p.x < r[2] && p.y < r[3])?;
    let h = to_params(&blocks[b].1);
    let (y, _) = project(&h, p);
    Some((y, point_jacobian(&h, p, y)))
}

/// d pi(H p) / d p for homography parameters `h`, with `y = pi(H p)`.
fn point_jacobian(h: &[f64], p: Vec2, y: Vec2) -> [[f64; 2]; 2] {
    let d = h[6] * p.x + h[7] * p.y + 1.0;
    let d = if d.abs() < 1e-9 {
        1e-9f64.copysign(d)
    } else {
        d
    };
    [
        [(h[0] - y.x * h[6]) / d, (h[1] - y.x * h[7]) / d],
        [(h[3] - y.y * h[6]) / d, (h[4] - y.y * h[7]) / d],
    ]
}

/// One frame's side of a constraint: the frame's slot, the pixel in focal lengths
/// about the principal point, and the shift direction weighted by each knot (zero for
/// flat print; set by [`Side::pointed`]), for the plane point `y` the frame's map puts
/// it at, under the frame's flash and lens.
#[derive(Clone, Copy)]
struct Side {
    slot: usize,
    xn: Vec2,
    dir: [Vec2; K],
    y: Vec2,
    light: Vec3,
    lens: Vec3,
    texture: bool,
}

impl Side {
    fn new(slot: usize, xn: Vec2, y: Vec2, light: Vec3, lens: Vec3, texture: bool) -> Self {
        Self {
            slot,
            xn,
            dir: [Vec2::zeros(); K],
            y,
            light,
            lens,
            texture,
        }
    }

    /// The same side with its shift pointing at the centre `w` ([`centre`]).
    fn pointed(self, w: f64) -> Self {
        let dir = if self.texture {
            directions(centre(self.light, self.lens, w), self.y)
        } else {
            [Vec2::zeros(); K]
        };
        Self { dir, ..self }
    }
}

#[derive(Clone, Copy)]
enum Obs {
    Pair(Side, Side),
    Anchor(Side, Vec2, f64),
}

impl Obs {
    fn pointed(&self, w: f64) -> Self {
        match *self {
            Obs::Pair(a, b) => Obs::Pair(a.pointed(w), b.pointed(w)),
            Obs::Anchor(a, x, wt) => Obs::Anchor(a.pointed(w), x, wt),
        }
    }
}

/// Model state: per-frame homography parameters, then lens and curve.
struct Model {
    frames: Vec<[f64; 8]>,
    shared: [f64; SHARED],
}

impl Model {
    /// Plane point of a side (shift removed) with its Jacobian entries as (column,
    /// d/dx, d/dy).
    fn side(&self, s: &Side, with_curve: bool, jac: &mut Vec<(usize, Vec2)>, sign: f64) -> Vec2 {
        let (a1, a2) = (self.shared[0], self.shared[1]);
        let r2 = s.xn.norm_squared();
        let u = s.xn * (1.0 + a1 * r2 + a2 * r2 * r2);
        let g = &self.frames[s.slot];
        let (y, jg) = project(g, u);
        for k in 0..8 {
            jac.push((8 * s.slot + k, sign * Vec2::new(jg[0][k], jg[1][k])));
        }
        let jp = point_jacobian(g, u, y);
        let apply = |v: Vec2| {
            Vec2::new(
                jp[0][0] * v.x + jp[0][1] * v.y,
                jp[1][0] * v.x + jp[1][1] * v.y,
            )
        };
        let base = 8 * self.frames.len();
        jac.push((base, sign * apply(s.xn * r2)));
        jac.push((base + 1, sign * apply(s.xn * r2 * r2)));
        let mut out = y;
        if with_curve {
            for k in 0..K {
                out -= s.dir[k] * self.shared[2 + k];
                jac.push((base + 2 + k, -sign * s.dir[k]));
            }
        }
        out
    }

    fn residual(&self, o: &Obs, with_curve: bool, jac: &mut Vec<(usize, Vec2)>) -> (Vec2, f64) {
        jac.clear();
        match o {
            Obs::Pair(a, b) => {
                let ya = self.side(a, with_curve, jac, 1.0);
                let yb = self.side(b, with_curve, jac, -1.0);
                (ya - yb, 1.0)
            }
            Obs::Anchor(a, x, w) => (self.side(a, with_curve, jac, 1.0) - x, *w),
        }
    }

    fn len(&self) -> usize {
        8 * self.frames.len() + SHARED
    }

    fn apply_step(&mut self, dx: &DVector<f64>) {
        for (i, f) in self.frames.iter_mut().enumerate() {
            for k in 0..8 {
                f[k] += dx[8 * i + k];
            }
        }
        let base = 8 * self.frames.len();
        for k in 0..SHARED {
            self.shared[k] += dx[base + k];
        }
    }
}

/// `J^T W J` and `J^T W r`.
type NormalEquations = (DMatrix<f64>, DVector<f64>);

/// Robust (Huber) cost and normal equations of the model over the observations.
fn assemble(
    m: &Model,
    obs: &[Obs],
    huber: f64,
    with_curve: bool,
    normal: bool,
) -> (f64, f64, Option<NormalEquations>) {
    let n = m.len();
    let mut ne = normal.then(|| (DMatrix::<f64>::zeros(n, n), DVector::<f64>::zeros(n)));
    let (mut cost, mut wsum) = (0.0, 0.0);
    let mut jac = Vec::with_capacity(2 * (8 + SHARED));
    for o in obs {
        let (r, w) = m.residual(o, with_curve, &mut jac);
        let e = r.norm();
        if !e.is_finite() {
            continue;
        }
        let hw = if e <= huber { 1.0 } else { huber / e };
        let w = w * hw;
        cost += w * e * e;
        wsum += w;
        if let Some((a, g)) = &mut ne {
            // The lower triangle only (`J^T W J` is symmetric; the Cholesky factorisation
            // reads no more), each entry summed in the same order as the full product;
            // mirrored once below.
            let lower = a.as_mut_slice();
            for (ci, ji) in &jac {
                g[*ci] += w * ji.dot(&r);
                for (cj, jj) in &jac {
                    if cj <= ci {
                        lower[cj * n + ci] += w * ji.dot(jj);
                    }
                }
            }
        }
    }
    if let Some((a, _)) = &mut ne {
        a.fill_upper_triangle_with_lower_triangle();
    }
    (cost, wsum, ne)
}

/// Gauss-Newton with Levenberg damping; returns the final normal matrix (for the
/// standard errors) and the robust cost.
fn fit(
    m: &mut Model,
    obs: &[Obs],
    huber: f64,
    with_curve: bool,
) -> Result<(DMatrix<f64>, f64, f64), AlignError> {
    let base = 8 * m.frames.len();
    let mut lambda = 1e-6;
    let (mut cost, mut wsum, _) = assemble(m, obs, huber, with_curve, false);
    for _ in 0..12 {
        let (_, _, ne) = assemble(m, obs, huber, with_curve, true);
        let Some((mut a, g)) = ne else { break };
        let scale = (0..a.nrows()).map(|i| a[(i, i)]).fold(0.0, f64::max);
        for i in 0..a.nrows() {
            let unused = !with_curve && i >= base + 2;
            a[(i, i)] += if unused {
                1.0
            } else {
                lambda * (a[(i, i)] + 1e-9 * scale)
            };
        }
        let Some(chol) = a.cholesky() else {
            lambda *= 10.0;
            continue;
        };
        let dx = -chol.solve(&g);
        let before = (m.frames.clone(), m.shared);
        m.apply_step(&dx);
        let (c, w, _) = assemble(m, obs, huber, with_curve, false);
        if c.is_finite() && c <= cost {
            let done = (cost - c) < 1e-9 * cost;
            cost = c;
            wsum = w;
            lambda = (lambda * 0.3).max(1e-12);
            if done {
                break;
            }
        } else {
            (m.frames, m.shared) = before;
            lambda *= 10.0;
        }
    }
    let (_, _, ne) = assemble(m, obs, huber, with_curve, true);
    let a = ne
        .map(|(a, _)| a)
        .ok_or_else(|| AlignError::Solve("relief model: no normal equations".into()))?;
    Ok((a, cost, wsum))
}

/// Kept flash frames of a registration by (stream, frame number): their index in it.
fn kept_flash_frames(result: &Registration) -> HashMap<(u32, u64), usize> {
    result
        .frames
        .iter()
        .enumerate()
        .filter(|(_, f)| f.stream == 0)
        .map(|(k, f)| ((f.stream, f.index), k))
        .collect()
}

/// Fit the rigid model to the correspondences of the flash frames that `result`
/// kept, with `result`'s maps and lights for each point's light tangent; the summary
/// says whether to apply the curve returned (cm at each knot; zero, with a `note`,
/// where too few marker corners make it meaningless).
pub(crate) fn estimate(
    matched: &Matched,
    result: &Registration,
    reference_weight: f64,
) -> Result<(ReliefSummary, [f64; K]), AlignError> {
    let mut summary = ReliefSummary {
        knots_t: KNOTS.to_vec(),
        centre_weight: 1.0,
        ..Default::default()
    };
    let kept = kept_flash_frames(result);
    // Matched frame -> (slot in the model, kept frame).
    let mut slots: HashMap<usize, (usize, usize)> = HashMap::new();
    for (i, f) in matched.frames.iter().enumerate() {
        if let Some(&k) = kept.get(&(f.stream, f.index)) {
            slots.insert(i, (slots.len(), k));
        }
    }
    summary.frames = slots.len();
    let kin = matched.intrinsics;
    let side = |i: usize, p: Vec2, texture: bool| -> Option<Side> {
        let &(slot, k) = slots.get(&i)?;
        let (y, _) = map_at(&result.mappings[k], p)?;
        Some(Side::new(
            slot,
            kin.pixel_to_normalized(p),
            y,
            result.lights[k],
            result.poses[k].centre,
            texture,
        ))
    };
    // Texture matches thinned evenly to at most `MAX_TEXTURE` (the model has 8
    // unknowns a frame and 10 shared; the paper preset has 450,000 matches).
    let texture: usize = matched
        .fine
        .iter()
        .filter_map(|(_, _, r)| r.as_ref().map(|(a, _, _)| a.len()))
        .sum::<usize>()
        + matched.anchors.iter().map(Vec::len).sum::<usize>();
    let stride = texture.div_ceil(MAX_TEXTURE).max(1);
    let mut obs = Vec::new();
    // One count over all texture correspondences, so that a pair with fewer matches
    // than the stride is not always represented by its first.
    let mut n = 0usize;
    let mut take = || {
        n += 1;
        (n - 1).is_multiple_of(stride)
    };
    for (i, j, r) in &matched.fine {
        let Some((a, b, _)) = r else { continue };
        for (p, q) in a.iter().zip(b) {
            if !take() {
                continue;
            }
            let (p, q) = (Vec2::new(p[0], p[1]), Vec2::new(q[0], q[1]));
            if let (Some(sa), Some(sb)) = (side(*i, p, true), side(*j, q, true)) {
                obs.push(Obs::Pair(sa, sb));
            }
        }
    }
    for i in 0..matched.frames.len() {
        for (p, x) in &matched.anchors[i] {
            if !take() {
                continue;
            }
            if let Some(s) = side(i, Vec2::new(p[0], p[1]), true) {
                obs.push(Obs::Anchor(s, *x, reference_weight));
            }
        }
        for (p, x) in &matched.marker_anchors[i] {
            if let Some(s) = side(i, *p, false) {
                obs.push(Obs::Anchor(s, *x, 4.0));
                summary.marker_corners += 1;
            }
        }
    }
    summary.constraints = obs.len();
    if slots.len() < 3 {
        summary.note = Some(format!("{} kept flash frames: not measured", slots.len()));
        return Ok((summary, [0.0; K]));
    }
    // Start: each frame's map over a 9 x 9 grid, fitted by one homography on the
    // frame's pixels in focal lengths.
    let mut frames = vec![[0.0; 8]; slots.len()];
    for (i, &(slot, k)) in &slots {
        let f = &matched.frames[*i];
        let (mut src, mut dst) = (Vec::new(), Vec::new());
        for gy in 0..9 {
            for gx in 0..9 {
                let p = Vec2::new(
                    (0.02 + 0.96 * f64::from(gx) / 8.0) * f64::from(f.width),
                    (0.02 + 0.96 * f64::from(gy) / 8.0) * f64::from(f.height),
                );
                if let Some((y, _)) = map_at(&result.mappings[k], p) {
                    src.push(kin.pixel_to_normalized(p));
                    dst.push(y);
                }
            }
        }
        let h = Homography::from_correspondences(&src, &dst)
            .map_err(|e| AlignError::Solve(format!("relief model start: {e}")))?;
        frames[slot] = to_params(&h.0);
    }
    let huber = 2.0 * matched.cm_per_px;
    let curve = solve_model(frames, &obs, huber, &mut summary)?;
    if summary.marker_corners < MIN_MARKER_CORNERS {
        // The curve's shape still shows (its share of the cost), its size does not.
        summary.applied = false;
        summary.note = Some(format!(
            "{} marker corners in the kept flash frames, at least {MIN_MARKER_CORNERS} needed to tell a relief shift from a change of scale: not corrected",
            summary.marker_corners
        ));
        return Ok((summary, [0.0; K]));
    }
    Ok((summary, curve))
}

/// Fit the rigid model from `frames` (homography parameters per slot) without the
/// curve, then with it pointing at each of [`CENTRE_WEIGHTS`]; fills the summary's
/// figures for the centre with the lowest cost and returns its curve (cm).
fn solve_model(
    frames: Vec<[f64; 8]>,
    obs: &[Obs],
    huber: f64,
    summary: &mut ReliefSummary,
) -> Result<[f64; K], AlignError> {
    let mut flat = Model {
        frames,
        shared: [0.0; SHARED],
    };
    let (_, c0, w0) = fit(&mut flat, obs, huber, false)?;
    let mean = |c: f64, ws: f64| c / ws.max(1e-12);
    let mut best: Option<(Model, DMatrix<f64>, f64, f64, f64)> = None;
    for w in CENTRE_WEIGHTS {
        let pointed: Vec<Obs> = obs.iter().map(|o| o.pointed(w)).collect();
        let mut m = Model {
            frames: flat.frames.clone(),
            shared: flat.shared,
        };
        let (a, c, ws) = fit(&mut m, &pointed, huber, true)?;
        if best.as_ref().is_none_or(|b| mean(c, ws) < mean(b.2, b.3)) {
            best = Some((m, a, c, ws, w));
        }
    }
    let Some((model, a, c1, w1, w)) = best else {
        return Err(AlignError::Solve("relief model: no centre tried".into()));
    };
    summary.centre_weight = w;
    summary.rms_um = [1e4 * mean(c0, w0).sqrt(), 1e4 * mean(c1, w1).sqrt()];
    summary.lens = [model.shared[0], model.shared[1]];
    summary.gain = if c0 > 0.0 && w0 > 0.0 && w1 > 0.0 {
        1.0 - (c1 / w1) / (c0 / w0)
    } else {
        0.0
    };
    summary.applied = summary.gain >= MIN_GAIN;
    let dof = (2 * obs.len()).saturating_sub(model.len()).max(1) as f64;
    let sigma2 = c1 / dof;
    let base = 8 * model.frames.len();
    let cov = a.try_inverse();
    let mut curve = [0.0; K];
    summary.shift_um.clear();
    summary.shift_um_stderr.clear();
    for k in 0..K {
        curve[k] = model.shared[2 + k];
        summary.shift_um.push(1e4 * curve[k]);
        let var = cov
            .as_ref()
            .map(|c| c[(base + 2 + k, base + 2 + k)] * sigma2)
            .unwrap_or(f64::NAN);
        summary.shift_um_stderr.push(if var.is_finite() {
            1e4 * var.sqrt()
        } else {
            -1.0
        });
    }
    Ok(curve)
}

/// Move every texture correspondence of the kept flash frames (matches between
/// frames and with the reference photo) by the curve's shift towards the centre
/// `centre_weight` ([`centre`]), to where the plane point it shows lies under
/// `result`'s maps. Marker corners stay.
pub(crate) fn correct(
    matched: &mut Matched,
    result: &Registration,
    curve_cm: &[f64; K],
    centre_weight: f64,
) {
    let kept = kept_flash_frames(result);
    let of: Vec<Option<usize>> = matched
        .frames
        .iter()
        .map(|f| kept.get(&(f.stream, f.index)).copied())
        .collect();
    let moved = |k: usize, p: [f64; 2]| -> [f64; 2] {
        let pv = Vec2::new(p[0], p[1]);
        let Some((y, j)) = map_at(&result.mappings[k], pv) else {
            return p;
        };
        let c = centre(result.lights[k], result.poses[k].centre, centre_weight);
        let s = shift_at(curve_cm, c, y);
        let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
        if det.abs() < 1e-18 {
            return p;
        }
        // p' = p - J^-1 s
        let dx = (j[1][1] * s.x - j[0][1] * s.y) / det;
        let dy = (-j[1][0] * s.x + j[0][0] * s.y) / det;
        [p[0] - dx, p[1] - dy]
    };
    for (i, j, r) in &mut matched.fine {
        let Some((a, b, _)) = r else { continue };
        if let Some(k) = of[*i] {
            for p in a.iter_mut() {
                *p = moved(k, *p);
            }
        }
        if let Some(k) = of[*j] {
            for q in b.iter_mut() {
                *q = moved(k, *q);
            }
        }
    }
    for (i, anchors) in matched.anchors.iter_mut().enumerate() {
        if let Some(k) = of[i] {
            for (p, _) in anchors.iter_mut() {
                *p = moved(k, *p);
            }
        }
    }
}

#[cfg(test)]
mod tests;
