//! Accuracy of fitted maps against known maps (the simulator's ground truth): diffuse
//! albedo error after one global scale factor, normal angle error and relighting error
//! under held-out lights. Truth maps may have another grid: they are sampled
//! bilinearly at each fitted pixel's plane position.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use svbrdf_core::brdf::{BrdfModel, BrdfParams, ModelKind};
use svbrdf_core::geometry::{Vec2, Vec3};
use svbrdf_core::image::ImageF32;
use svbrdf_core::plane::PlaneGrid;

use crate::render::relight;

/// Known maps.
pub struct Truth {
    /// Their grid.
    pub grid: PlaneGrid,
    /// Diffuse albedo, linear RGB.
    pub diffuse: ImageF32,
    /// Specular albedo, linear RGB.
    pub specular: ImageF32,
    /// Roughness: alpha_x, alpha_y in the first two channels.
    pub roughness: ImageF32,
    /// Unit normals.
    pub normal: ImageF32,
    /// Light intensity the held-out images were rendered with (linear value * cm^2).
    pub light_intensity: f64,
    /// 1 where material is visible.
    pub mask: ImageF32,
    /// Held-out images with their light and camera positions (cm).
    pub holdout: Vec<(ImageF32, Vec3, Vec3)>,
    /// The reflectance model the truth was rendered with.
    pub model: ModelKind,
}

/// Accuracy figures.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Accuracy {
    /// Pixels compared (inside both grids and on material).
    pub pixels: usize,
    /// Global scale applied to the fitted albedos before comparing (least squares).
    pub albedo_scale: f64,
    /// Diffuse albedo RMSE after scaling, over pixels and channels.
    pub diffuse_rmse: f64,
    /// The same after averaging both maps over 1 mm blocks (what remains is not
    /// pixel-scale texture or noise).
    pub diffuse_rmse_1mm: f64,
    /// Mean normal angle error, degrees.
    pub normal_mean_deg: f64,
    /// Median normal angle error, degrees.
    pub normal_median_deg: f64,
    /// Relighting error per held-out light: RMSE of linear radiance over mean radiance.
    /// Rendered with the intensity the fit used, which reproduces absolute radiance
    /// whether or not the intensity was known (the fit determines `I * rho`).
    pub relight_relative_rmse: Vec<f64>,
    /// Mean of the above.
    pub relight_relative_rmse_mean: f64,
    /// Per held-out light: mean fitted radiance over mean true radiance (1 = no bias).
    pub relight_mean_ratio: Vec<f64>,
    /// Relighting error after averaging both images over 1 mm x 1 mm blocks: separates
    /// errors of the reflectance model (which survive averaging) from pixel-scale
    /// texture and noise (which do not).
    pub relight_relative_rmse_1mm: Vec<f64>,
    /// One brightness factor for every held-out light (their summed true radiance over
    /// the summed fitted radiance): where a capture does not fix absolute brightness
    /// (exposure gains are estimated up to one common factor), the relighting errors
    /// above carry it, and the two below do not.
    #[serde(default)]
    pub relight_brightness_scale: f64,
    /// `relight_relative_rmse` with the fitted radiance times `relight_brightness_scale`.
    #[serde(default)]
    pub relight_relative_rmse_rescaled: Vec<f64>,
    /// `relight_relative_rmse_1mm` with the fitted radiance times
    /// `relight_brightness_scale`.
    #[serde(default)]
    pub relight_relative_rmse_1mm_rescaled: Vec<f64>,
}

/// RMS difference of block means, from per-block sums `[ours r g b, truth r g b, n]`.
fn block_rmse(blocks: &[[f64; 7]]) -> f64 {
    let (mut se, mut n) = (0.0, 0.0);
    for b in blocks.iter().filter(|b| b[6] > 0.0) {
        for c in 0..3 {
            se += ((b[c] - b[3 + c]) / b[6]).powi(2);
        }
        n += 3.0;
    }
    (se / f64::max(n, 1.0)).sqrt()
}

fn sample(img: &ImageF32, grid: &PlaneGrid, q: Vec2) -> [f64; 3] {
    let p = grid.to_pixel(q);
    let mut o = [0f32; 3];
    img.sample_bilinear(p.x, p.y, &mut o);
    o.map(f64::from)
}

/// The map pixels compared with the truth (index, plane point): on the material, and
/// half a truth pixel inside the truth region, so bilinear samples are interior.
fn compared_pixels(grid: &PlaneGrid, truth: &Truth) -> Vec<(usize, Vec2)> {
    let r = truth.grid.region;
    let m = 0.5 / truth.grid.px_per_cm;
    let mut idx = Vec::new();
    for row in 0..grid.height {
        for col in 0..grid.width {
            let q = grid.pixel_centre(col, row);
            if q.x < r.x_min + m || q.x > r.x_max - m || q.y < r.y_min + m || q.y > r.y_max - m {
                continue;
            }
            if sample(&truth.mask, &truth.grid, q)[0] < 0.999 {
                continue;
            }
            idx.push((row * grid.width + col, q));
        }
    }
    idx
}

/// Compare fitted maps with the truth.
pub fn evaluate(
    grid: &PlaneGrid,
    params: &[BrdfParams],
    model: &dyn BrdfModel,
    intensity: [f64; 3],
    truth: &Truth,
) -> Accuracy {
    let idx = compared_pixels(grid, truth);
    let (mut ft, mut ff) = (0.0, 0.0);
    for &(i, q) in &idx {
        let t = sample(&truth.diffuse, &truth.grid, q);
        for c in 0..3 {
            ft += params[i].rho_d[c] * t[c];
            ff += params[i].rho_d[c] * params[i].rho_d[c];
        }
    }
    let scale = if ff > 0.0 { ft / ff } else { 1.0 };
    let block = (0.1 * grid.px_per_cm).round().max(1.0) as usize;
    let (bw, bh) = (grid.width.div_ceil(block), grid.height.div_ceil(block));
    let mut dblocks = vec![[0.0f64; 7]; bw * bh];
    let mut se = 0.0;
    let mut angles = Vec::with_capacity(idx.len());
    for &(i, q) in &idx {
        let t = sample(&truth.diffuse, &truth.grid, q);
        let b = (i / grid.width / block) * bw + (i % grid.width) / block;
        dblocks[b][6] += 1.0;
        for c in 0..3 {
            dblocks[b][c] += scale * params[i].rho_d[c];
            dblocks[b][3 + c] += t[c];
            se += (scale * params[i].rho_d[c] - t[c]).powi(2);
        }
        let tn = sample(&truth.normal, &truth.grid, q);
        let tn = Vec3::new(tn[0], tn[1], tn[2])
            .try_normalize(1e-9)
            .unwrap_or_else(Vec3::z);
        let cos = params[i].normal().dot(&tn).clamp(-1.0, 1.0);
        angles.push(cos.acos().to_degrees());
    }
    let n = idx.len().max(1) as f64;
    let normal_mean_deg = angles.iter().sum::<f64>() / n;
    let normal_median_deg = if angles.is_empty() {
        0.0
    } else {
        let k = angles.len() / 2;
        *angles.select_nth_unstable_by(k, f64::total_cmp).1
    };
    let block = (0.1 * grid.px_per_cm).round().max(1.0) as usize;
    let (bw, bh) = (grid.width.div_ceil(block), grid.height.div_ceil(block));
    let mut relight_relative_rmse = Vec::new();
    let mut relight_mean_ratio = Vec::new();
    let mut relight_relative_rmse_1mm = Vec::new();
    // Per light: mean true radiance, sums of ours^2, ours * truth and truth^2, blocks.
    let mut per_light: Vec<(f64, [f64; 3], Vec<[f64; 7]>)> = Vec::new();
    let (mut all_truth, mut all_ours) = (0.0, 0.0);
    for (img, light, camera) in &truth.holdout {
        let ours = relight(grid, params, model, intensity, *light, *camera);
        let (mut se, mut sum, mut sum_ours) = (0.0, 0.0, 0.0);
        let mut moments = [0.0f64; 3];
        // Per block: sum of ours, sum of truth (per channel), count.
        let mut blocks = vec![[0.0f64; 7]; bw * bh];
        for &(i, q) in &idx {
            let t = sample(img, &truth.grid, q);
            let b = (i / grid.width / block) * bw + (i % grid.width) / block;
            for c in 0..3 {
                let o = f64::from(ours.data[3 * i + c]);
                se += (o - t[c]).powi(2);
                moments[0] += o * o;
                moments[1] += o * t[c];
                moments[2] += t[c] * t[c];
                sum += t[c];
                sum_ours += o;
                blocks[b][c] += o;
                blocks[b][3 + c] += t[c];
            }
            blocks[b][6] += 1.0;
        }
        let mean = sum / (3.0 * n);
        if mean > 0.0 {
            relight_relative_rmse.push((se / (3.0 * n)).sqrt() / mean);
            relight_mean_ratio.push(sum_ours / sum);
            relight_relative_rmse_1mm.push(block_rmse(&blocks) / mean);
        } else {
            relight_relative_rmse.push(0.0);
            relight_mean_ratio.push(0.0);
            relight_relative_rmse_1mm.push(0.0);
        }
        all_truth += sum;
        all_ours += sum_ours;
        per_light.push((mean, moments, blocks));
    }
    let g = if all_ours > 0.0 {
        all_truth / all_ours
    } else {
        1.0
    };
    let (mut relight_relative_rmse_rescaled, mut relight_relative_rmse_1mm_rescaled) =
        (Vec::new(), Vec::new());
    for (mean, [oo, ot, tt], mut blocks) in per_light {
        if mean <= 0.0 {
            relight_relative_rmse_rescaled.push(0.0);
            relight_relative_rmse_1mm_rescaled.push(0.0);
            continue;
        }
        let se = (g * g * oo - 2.0 * g * ot + tt).max(0.0);
        relight_relative_rmse_rescaled.push((se / (3.0 * n)).sqrt() / mean);
        for b in &mut blocks {
            for v in &mut b[..3] {
                *v *= g;
            }
        }
        relight_relative_rmse_1mm_rescaled.push(block_rmse(&blocks) / mean);
    }
    let relight_relative_rmse_mean =
        relight_relative_rmse.iter().sum::<f64>() / relight_relative_rmse.len().max(1) as f64;
    Accuracy {
        pixels: idx.len(),
        albedo_scale: scale,
        diffuse_rmse: (se / (3.0 * n)).sqrt(),
        diffuse_rmse_1mm: block_rmse(&dblocks),
        normal_mean_deg,
        normal_median_deg,
        relight_relative_rmse,
        relight_relative_rmse_mean,
        relight_mean_ratio,
        relight_relative_rmse_1mm,
        relight_brightness_scale: g,
        relight_relative_rmse_rescaled,
        relight_relative_rmse_1mm_rescaled,
    }
}

/// Relighting error by the fit's own specular confidence: does the confidence map
/// point at the parts the fit gets wrong under new lights?
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct ConfidenceBreakdown {
    /// Classes, in order: highlight peak seen (1), only its flank or clipped (0.5),
    /// never seen (0).
    pub classes: [String; 3],
    /// Share of the compared pixels in each class.
    pub shares: [f64; 3],
    /// Per class, the relative RMSE of relighting (as `relight_relative_rmse`, each
    /// class against its own mean radiance), averaged over the held-out lights;
    /// `None` for an empty class.
    pub relight_relative_rmse: [Option<f64>; 3],
}

/// [`ConfidenceBreakdown`] of fitted maps with their per-pixel confidence
/// (`[diffuse, specular, normal]`, as `maps/confidence.exr`).
pub fn relight_by_confidence(
    grid: &PlaneGrid,
    params: &[BrdfParams],
    confidence: &[[f32; 3]],
    model: &dyn BrdfModel,
    intensity: [f64; 3],
    truth: &Truth,
) -> ConfidenceBreakdown {
    let class = |c: f32| svbrdf_core::confidence::SpecularSeen::of(c) as usize;
    let idx: Vec<(usize, Vec2, usize)> = compared_pixels(grid, truth)
        .into_iter()
        .filter(|(i, _)| *i < confidence.len())
        .map(|(i, q)| (i, q, class(confidence[i][1])))
        .collect();
    let mut counts = [0usize; 3];
    for &(_, _, k) in &idx {
        counts[k] += 1;
    }
    let total = idx.len().max(1) as f64;
    let mut per_class = [0.0f64; 3];
    let mut lights = 0.0;
    for (img, light, camera) in &truth.holdout {
        let ours = relight(grid, params, model, intensity, *light, *camera);
        let (mut se, mut sum) = ([0.0f64; 3], [0.0f64; 3]);
        for &(i, q, k) in &idx {
            let t = sample(img, &truth.grid, q);
            for c in 0..3 {
                se[k] += (f64::from(ours.data[3 * i + c]) - t[c]).powi(2);
                sum[k] += t[c];
            }
        }
        for k in 0..3 {
            let n = 3.0 * counts[k] as f64;
            if n > 0.0 && sum[k] > 0.0 {
                per_class[k] += (se[k] / n).sqrt() / (sum[k] / n);
            }
        }
        lights += 1.0;
    }
    ConfidenceBreakdown {
        classes: [
            "highlight peak seen".into(),
            "flank or clipped peak only".into(),
            "highlight never seen".into(),
        ],
        shares: counts.map(|c| c as f64 / total),
        relight_relative_rmse: std::array::from_fn(|k| {
            (counts[k] > 0 && lights > 0.0).then(|| per_class[k] / lights)
        }),
    }
}

/// Where the relighting error lies, by what the true material is at each pixel: the
/// classes say which part of the reflectance a fit gets wrong under new lights (a
/// research figure of `bench --fit-maps`, not a quality score).
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct MaterialBreakdown {
    /// Classes of the true maps, in order: matte (mean `rho_s` < 0.05), glossy
    /// (isotropic, `alpha` < 0.2), anisotropic (`alpha` ratio > 1.5), broad lobe (the
    /// rest), and border (within two truth pixels of another class: thin seams and
    /// edges, where the video's blur mixes neighbours).
    pub classes: [String; 5],
    /// Share of the compared pixels in each class.
    pub shares: [f64; 5],
    /// Per held-out light, each class's share of that light's squared error.
    pub error_share: Vec<[f64; 5]>,
    /// Per held-out light, each class's mean fitted radiance over its mean true
    /// radiance (0 for an empty class): a bias that survives averaging.
    pub mean_ratio: Vec<[f64; 5]>,
    /// Each class's share of the diffuse albedo's squared error (after the global
    /// scale, as `diffuse_rmse`).
    pub diffuse_error_share: [f64; 5],
    /// Per class, the mean fitted over the mean true value of the specular albedo
    /// (channel mean, after the global scale), `alpha_x` and `alpha_y` (0 for an empty
    /// class).
    pub lobe_ratio: [[f64; 3]; 5],
}

/// Class of the true material at truth pixel `t` (see [`MaterialBreakdown`]), without
/// the border class.
fn true_class(truth: &Truth, t: usize) -> usize {
    let s = &truth.specular.data[3 * t..3 * t + 3];
    let rc = truth.roughness.channels;
    let (ax, ay) = (
        truth.roughness.data[rc * t],
        truth.roughness.data[rc * t + 1],
    );
    if (s[0] + s[1] + s[2]) / 3.0 < 0.05 {
        0
    } else if ax.max(ay) > 1.5 * ax.min(ay) {
        2
    } else if ax.max(ay) < 0.2 {
        1
    } else {
        3
    }
}

/// [`MaterialBreakdown`] of fitted maps.
pub fn relight_by_material(
    grid: &PlaneGrid,
    params: &[BrdfParams],
    model: &dyn BrdfModel,
    intensity: [f64; 3],
    truth: &Truth,
) -> MaterialBreakdown {
    let (tw, th) = (truth.grid.width as i64, truth.grid.height as i64);
    let class_at = |c: i64, r: i64| true_class(truth, (r * tw + c) as usize);
    let idx: Vec<(usize, Vec2, usize)> = compared_pixels(grid, truth)
        .into_iter()
        .map(|(i, q)| {
            let p = truth.grid.to_pixel(q);
            let (c, r) = (
                (p.x.round() as i64).clamp(0, tw - 1),
                (p.y.round() as i64).clamp(0, th - 1),
            );
            let k = class_at(c, r);
            let border = (-2..=2).any(|dy: i64| {
                (-2..=2).any(|dx: i64| {
                    let (x, y) = (c + dx, r + dy);
                    x >= 0 && y >= 0 && x < tw && y < th && class_at(x, y) != k
                })
            });
            (i, q, if border { 4 } else { k })
        })
        .collect();
    let mut counts = [0usize; 5];
    for &(_, _, k) in &idx {
        counts[k] += 1;
    }
    let total = idx.len().max(1) as f64;
    let (mut ft, mut ff) = (0.0, 0.0);
    for &(i, q, _) in &idx {
        let t = sample(&truth.diffuse, &truth.grid, q);
        for c in 0..3 {
            ft += params[i].rho_d[c] * t[c];
            ff += params[i].rho_d[c] * params[i].rho_d[c];
        }
    }
    let scale = if ff > 0.0 { ft / ff } else { 1.0 };
    let mut dse = [0.0f64; 5];
    for &(i, q, k) in &idx {
        let t = sample(&truth.diffuse, &truth.grid, q);
        for c in 0..3 {
            dse[k] += (scale * params[i].rho_d[c] - t[c]).powi(2);
        }
    }
    let dall: f64 = dse.iter().sum();
    // Per class: fitted and true sums of rho_s, alpha_x, alpha_y.
    let mut lobe = [[0.0f64; 6]; 5];
    let rc = truth.roughness.channels;
    for &(i, q, k) in &idx {
        let t = sample(&truth.specular, &truth.grid, q);
        let p = truth.grid.to_pixel(q);
        let (c, r) = (
            (p.x.round() as i64).clamp(0, tw - 1) as usize,
            (p.y.round() as i64).clamp(0, th - 1) as usize,
        );
        let a = &truth.roughness.data[rc * (r * tw as usize + c)..];
        let f = &params[i];
        let l = &mut lobe[k];
        l[0] += scale * (f.rho_s[0] + f.rho_s[1] + f.rho_s[2]) / 3.0;
        l[1] += (t[0] + t[1] + t[2]) / 3.0;
        l[2] += f.alpha_x;
        l[3] += f64::from(a[0]);
        l[4] += f.alpha_y;
        l[5] += f64::from(a[1]);
    }
    let ratio = |a: f64, b: f64| if b > 0.0 { a / b } else { 0.0 };
    let mut error_share = Vec::new();
    let mut mean_ratio = Vec::new();
    for (img, light, camera) in &truth.holdout {
        let ours = relight(grid, params, model, intensity, *light, *camera);
        let (mut se, mut sum_t, mut sum_o) = ([0.0f64; 5], [0.0f64; 5], [0.0f64; 5]);
        for &(i, q, k) in &idx {
            let t = sample(img, &truth.grid, q);
            for c in 0..3 {
                let o = f64::from(ours.data[3 * i + c]);
                se[k] += (o - t[c]).powi(2);
                sum_t[k] += t[c];
                sum_o[k] += o;
            }
        }
        let all: f64 = se.iter().sum();
        error_share.push(se.map(|e| if all > 0.0 { e / all } else { 0.0 }));
        mean_ratio.push(std::array::from_fn(|k| {
            if sum_t[k] > 0.0 {
                sum_o[k] / sum_t[k]
            } else {
                0.0
            }
        }));
    }
    MaterialBreakdown {
        classes: [
            "matte".into(),
            "glossy".into(),
            "anisotropic".into(),
            "broad lobe".into(),
            "border".into(),
        ],
        shares: counts.map(|c| c as f64 / total),
        error_share,
        mean_ratio,
        diffuse_error_share: dse.map(|e| if dall > 0.0 { e / dall } else { 0.0 }),
        lobe_ratio: lobe.map(|l| [ratio(l[0], l[1]), ratio(l[2], l[3]), ratio(l[4], l[5])]),
    }
}

/// What perfect maps lose to a blur: the true maps, each blurred by a Gaussian of
/// `sigma_px` of their own pixels (normals renormalised), compared with the truth as
/// fitted maps are. A capture whose video samples the surface at about one output
/// pixel per video pixel cannot give maps sharper than a fraction of a pixel, so these
/// figures bound what any fit that does not reconstruct detail below that scale can
/// reach. The simulator's own renderer looks material parameters up bilinearly, which
/// averaged over sample positions is a one-pixel tent (sigma = 0.41 pixel). The maps
/// are rendered with the truth's own model.
pub fn blurred_truth(truth: &Truth, sigma_px: f64) -> Accuracy {
    let (d, s, r, n) = (
        gaussian_blur(&truth.diffuse, sigma_px),
        gaussian_blur(&truth.specular, sigma_px),
        gaussian_blur(&truth.roughness, sigma_px),
        gaussian_blur(&truth.normal, sigma_px),
    );
    let params: Vec<BrdfParams> = (0..truth.grid.len())
        .map(|i| {
            let mut p = crate::output::params_from_maps([&d, &s, &r, &n], i);
            // A roughness map may hold 0 where the blur reaches no material.
            p.alpha_x = p.alpha_x.max(1e-3);
            p.alpha_y = p.alpha_y.max(1e-3);
            p
        })
        .collect();
    let i = truth.light_intensity;
    evaluate(&truth.grid, &params, truth.model.model(), [i; 3], truth)
}

/// Separable Gaussian blur (clamped at the border); `sigma_px <= 0` copies.
pub fn gaussian_blur(img: &ImageF32, sigma_px: f64) -> ImageF32 {
    if sigma_px <= 0.0 || !sigma_px.is_finite() {
        return img.clone();
    }
    let k = (3.0 * sigma_px).ceil() as isize;
    let mut w: Vec<f32> = (-k..=k)
        .map(|x| (-(x * x) as f64 / (2.0 * sigma_px * sigma_px)).exp() as f32)
        .collect();
    let sum: f32 = w.iter().sum();
    w.iter_mut().for_each(|v| *v /= sum);
    let (wd, ht, ch) = (img.width as isize, img.height as isize, img.channels);
    let pass = |src: &ImageF32, horizontal: bool| {
        let mut out = ImageF32::new(src.width, src.height, ch);
        out.data
            .par_chunks_mut(src.width * ch)
            .enumerate()
            .for_each(|(row, line)| {
                for col in 0..wd {
                    for (t, wt) in w.iter().enumerate() {
                        let o = t as isize - k;
                        let (c, r) = if horizontal {
                            ((col + o).clamp(0, wd - 1), row as isize)
                        } else {
                            (col, (row as isize + o).clamp(0, ht - 1))
                        };
                        let p = src.pixel(c as usize, r as usize);
                        for (q, v) in p.iter().enumerate() {
                            line[col as usize * ch + q] += wt * v;
                        }
                    }
                }
            });
        out
    };
    pass(&pass(img, true), false)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 2 x 1 cm truth: glossy left half, matte right half, one held-out light.
    fn halves() -> (Truth, Vec<BrdfParams>) {
        let grid = PlaneGrid::new(svbrdf_core::plane::Region::centred(2.0, 1.0), 10.0).unwrap();
        let glossy = |c: usize| c < grid.width / 2;
        let params: Vec<BrdfParams> = (0..grid.len())
            .map(|i| BrdfParams {
                rho_d: [0.3; 3],
                rho_s: if glossy(i % grid.width) {
                    [0.4; 3]
                } else {
                    [0.0; 3]
                },
                alpha_x: 0.1,
                alpha_y: 0.1,
                ..BrdfParams::default()
            })
            .collect();
        let map = |f: &dyn Fn(&BrdfParams) -> [f32; 3]| {
            let mut img = ImageF32::new(grid.width, grid.height, 3);
            for (px, p) in img.data.chunks_exact_mut(3).zip(&params) {
                px.copy_from_slice(&f(p));
            }
            img
        };
        let (light, camera) = (Vec3::new(0.5, 0.0, 3.0), Vec3::new(0.0, 0.0, 5.0));
        let model = ModelKind::Ward;
        let lit = relight(&grid, &params, model.model(), [10.0; 3], light, camera);
        let mut mask = ImageF32::new(grid.width, grid.height, 3);
        mask.data.fill(1.0);
        let truth = Truth {
            grid,
            diffuse: map(&|p| p.rho_d.map(|v| v as f32)),
            specular: map(&|p| p.rho_s.map(|v| v as f32)),
            roughness: map(&|p| [p.alpha_x as f32, p.alpha_y as f32, 0.0]),
            normal: map(&|_| [0.0, 0.0, 1.0]),
            light_intensity: 10.0,
            mask,
            holdout: vec![(lit, light, camera)],
            model,
        };
        (truth, params)
    }

    #[test]
    fn relighting_error_is_put_where_the_true_material_is_wrong() {
        let (truth, mut params) = halves();
        let w = truth.grid.width;
        // The matte half fitted too bright: all of the error is matte's, and only its
        // mean ratio moves.
        for (i, p) in params.iter_mut().enumerate() {
            if i % w >= w / 2 {
                p.rho_d = [0.45; 3];
            }
        }
        let b = relight_by_material(
            &truth.grid,
            &params,
            ModelKind::Ward.model(),
            [10.0; 3],
            &truth,
        );
        let share: f64 = b.shares.iter().sum();
        assert!((share - 1.0).abs() < 1e-9);
        // Two truth pixels either side of the middle are the border.
        assert!((b.shares[4] - 0.2).abs() < 0.051, "{:?}", b.shares);
        assert!((b.shares[0] - 0.4).abs() < 0.051 && (b.shares[1] - 0.4).abs() < 0.051);
        let e = b.error_share[0];
        assert!(e[1] < 1e-9 && e[2] == 0.0 && e[3] == 0.0, "{e:?}");
        assert!(e[0] > 0.5 && (e[0] + e[4] - 1.0).abs() < 1e-9, "{e:?}");
        let r = b.mean_ratio[0];
        assert!(
            (r[1] - 1.0).abs() < 1e-6 && r[0] > 1.2 && r[2] == 0.0,
            "{r:?}"
        );
    }

    #[test]
    fn relighting_errors_rescaled_for_brightness_forgive_one_factor_only() {
        let (truth, params) = halves();
        let model = ModelKind::Ward;
        // The right maps under an intensity 1.5 times too high (exposure gains known
        // only up to one factor): off by at least half, nothing off once rescaled.
        let a = evaluate(&truth.grid, &params, model.model(), [15.0; 3], &truth);
        assert!(a.relight_relative_rmse[0] >= 0.5, "{a:?}");
        assert!((a.relight_brightness_scale - 1.0 / 1.5).abs() < 1e-6);
        assert!(a.relight_relative_rmse_rescaled[0] < 1e-5, "{a:?}");
        assert!(a.relight_relative_rmse_1mm_rescaled[0] < 1e-5, "{a:?}");
        // A wrong lobe stays wrong after rescaling.
        let dull: Vec<BrdfParams> = params
            .iter()
            .map(|p| BrdfParams {
                rho_s: [0.0; 3],
                ..*p
            })
            .collect();
        let b = evaluate(&truth.grid, &dull, model.model(), [15.0; 3], &truth);
        assert!(b.relight_relative_rmse_rescaled[0] > 0.05, "{b:?}");
        // With the right brightness the rescaled figures equal the plain ones.
        let c = evaluate(&truth.grid, &dull, model.model(), [10.0; 3], &truth);
        assert!(c.relight_relative_rmse_rescaled[0] <= c.relight_relative_rmse[0] + 1e-12);
    }

    #[test]
    fn gaussian_blur_keeps_flat_images_and_mass_and_spreads_symmetrically() {
        let mut img = ImageF32::new(9, 7, 2);
        img.data.iter_mut().for_each(|v| *v = 0.25);
        let b = gaussian_blur(&img, 0.8);
        assert!(b.data.iter().all(|v| (v - 0.25).abs() < 1e-6));
        let mut imp = ImageF32::new(9, 9, 1);
        imp.pixel_mut(4, 4)[0] = 1.0;
        let b = gaussian_blur(&imp, 0.7);
        let sum: f32 = b.data.iter().sum();
        assert!((sum - 1.0).abs() < 1e-5);
        assert!(b.pixel(4, 4)[0] < 0.5);
        assert!((b.pixel(3, 4)[0] - b.pixel(5, 4)[0]).abs() < 1e-7);
        assert!((b.pixel(4, 3)[0] - b.pixel(3, 4)[0]).abs() < 1e-7);
        assert_eq!(gaussian_blur(&imp, 0.0), imp);
    }
}
