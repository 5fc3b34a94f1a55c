//! Held-out evaluation: fit on all frames but a few, then render the held-out frames
//! from their own camera and light positions and compare with the photographs
//! (RMSE and SSIM, in linear and in sRGB), as MaterialGAN-style projects report it.
//!
//! Comparisons happen on the fit's output grid: each held-out frame is resampled onto
//! the plane (bilinear, in linear RGB) through its registered mapping, and the fitted
//! maps are rendered there under the frame's point light, seen from its camera.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use svbrdf_core::capture::{PreparedMapping, RegisteredCapture};
use svbrdf_core::color::{linear_to_srgb, srgb8_to_linear_table};
use svbrdf_core::geometry::Vec3;
use svbrdf_core::image::{FrameImage, ImageF32};
use svbrdf_core::maps::{write_png, Encoding, PngDepth};
use svbrdf_core::plane::PlaneGrid;
use svbrdf_core::progress::Progress;
use svbrdf_core::CoreError;

use crate::render::relight_in_room;
use crate::{FitConfig, FitError, FrameSource};

/// File names inside an evaluation folder.
pub const EVAL_DIR: &str = "eval";
/// The figures.
pub const EVAL_FILE: &str = "eval.json";

/// The largest linear value a photo or frame can record (8-bit code 255, the top of a
/// 10-bit or HDR stream as we decode it: docs/CONVENTIONS.md). Renderings are clipped
/// here before the linear comparison, as the camera clipped the photo.
pub const RECORDED_MAX: f32 = 1.0;

/// Errors of one held-out image.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HoldoutError {
    /// Frame id in the capture.
    pub id: u32,
    /// Image file (image sources) or frame number (video).
    pub name: String,
    /// Camera position, cm.
    pub camera_position: [f64; 3],
    /// Light position, cm.
    pub light_position: [f64; 3],
    /// Compared pixels (those the frame sees).
    pub pixels: usize,
    /// RMSE of linear RGB, the rendering clipped at [`RECORDED_MAX`] as the camera
    /// would have recorded it (a highlight predicted at 20 where the photo shows its
    /// clipped 1 is right, not 19 off).
    pub rmse_linear: f64,
    /// RMSE divided by the photo's mean linear value.
    pub relative_rmse_linear: f64,
    /// [`rmse_linear`](Self::rmse_linear) without clipping the rendering (before
    /// session 26 this was `rmse_linear`).
    #[serde(default)]
    pub rmse_linear_unclipped: f64,
    /// The same divided by the photo's mean linear value.
    #[serde(default)]
    pub relative_rmse_linear_unclipped: f64,
    /// RMSE of sRGB-encoded values in [0, 1] (clamped).
    pub rmse_srgb: f64,
    /// Mean SSIM over the three channels, linear values (dynamic range 1; the rendering
    /// clipped at [`RECORDED_MAX`]).
    pub ssim_linear: f64,
    /// Mean SSIM over the three channels, sRGB values.
    pub ssim_srgb: f64,
    /// Photo | rendering | 4 x |difference| (sRGB PNG), relative to the evaluation folder.
    pub strip: String,
    /// Mean perceptual difference (NVIDIA's LDR-FLIP, in [0, 1], lower is better) over
    /// the compared pixels, where a FLIP evaluator was given.
    #[serde(default)]
    pub flip: Option<f64>,
}

/// A perceptual image difference computed by an outside tool (the binary runs NVIDIA's
/// FLIP evaluator); this crate only hands it the images.
pub trait ImageMetric {
    /// What it is, for the records (tool, version, settings).
    fn describe(&self) -> String;
    /// Mean difference over the pixels where `mask` is set, between two sRGB images in
    /// [0, 1] of the same size (3 channels).
    fn mean_error(
        &self,
        reference: &ImageF32,
        test: &ImageF32,
        mask: &[bool],
    ) -> Result<f64, FitError>;
}

/// What an evaluation found.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HoldoutReport {
    /// Held-out frame ids.
    pub holdout: Vec<u32>,
    /// Frames fitted.
    pub fitted_frames: usize,
    /// Model and whether the specular lobe was fitted.
    pub model: String,
    /// `true` for the Lambertian baseline (`rho_s = 0`).
    pub diffuse_only: bool,
    /// Per held-out image.
    pub images: Vec<HoldoutError>,
    /// Means over the held-out images.
    pub mean: MeanErrors,
    /// Seconds spent fitting.
    pub fit_seconds: f64,
    /// The perceptual metric behind the `flip` figures, where one was given.
    #[serde(default)]
    pub flip_metric: Option<String>,
}

/// Means over held-out images.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct MeanErrors {
    /// See [`HoldoutError`].
    pub rmse_linear: f64,
    /// See [`HoldoutError`].
    pub relative_rmse_linear: f64,
    /// See [`HoldoutError`].
    #[serde(default)]
    pub rmse_linear_unclipped: f64,
    /// See [`HoldoutError`].
    #[serde(default)]
    pub relative_rmse_linear_unclipped: f64,
    /// See [`HoldoutError`].
    pub rmse_srgb: f64,
    /// See [`HoldoutError`].
    pub ssim_linear: f64,
    /// See [`HoldoutError`].
    pub ssim_srgb: f64,
    /// See [`HoldoutError`]; over the images that have it.
    #[serde(default)]
    pub flip: Option<f64>,
}

impl MeanErrors {
    /// Mean of a list.
    pub fn of<'a>(errs: impl IntoIterator<Item = &'a HoldoutError>) -> Self {
        let mut m = Self::default();
        let mut n = 0.0;
        let (mut flip, mut nf) = (0.0, 0.0);
        for e in errs {
            if let Some(f) = e.flip {
                flip += f;
                nf += 1.0;
            }
            m.rmse_linear += e.rmse_linear;
            m.relative_rmse_linear += e.relative_rmse_linear;
            m.rmse_linear_unclipped += e.rmse_linear_unclipped;
            m.relative_rmse_linear_unclipped += e.relative_rmse_linear_unclipped;
            m.rmse_srgb += e.rmse_srgb;
            m.ssim_linear += e.ssim_linear;
            m.ssim_srgb += e.ssim_srgb;
            n += 1.0;
        }
        if n > 0.0 {
            m.rmse_linear /= n;
            m.relative_rmse_linear /= n;
            m.rmse_linear_unclipped /= n;
            m.relative_rmse_linear_unclipped /= n;
            m.rmse_srgb /= n;
            m.ssim_linear /= n;
            m.ssim_srgb /= n;
        }
        m.flip = (nf > 0.0).then(|| flip / nf);
        m
    }
}

/// Split a capture into the frames to fit and the held-out ones. Sources keep their
/// paths, made absolute against `dir` (the folder of the original `capture.json`), so
/// the training capture can be written anywhere.
pub fn split(
    capture: &RegisteredCapture,
    dir: &Path,
    holdout: &[u32],
) -> Result<(RegisteredCapture, RegisteredCapture), FitError> {
    let ids: Vec<u32> = capture.frames.iter().map(|f| f.id).collect();
    for h in holdout {
        if !ids.contains(h) {
            return Err(FitError::invalid(
                "held-out frame",
                h,
                format!(
                    "one of the capture's frame ids {}",
                    ids.iter()
                        .map(u32::to_string)
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            ));
        }
    }
    if holdout.is_empty() {
        return Err(FitError::invalid(
            "hold-out list",
            "(empty)",
            "at least one frame id",
        ));
    }
    if let Some(d) = holdout
        .iter()
        .enumerate()
        .find_map(|(i, h)| holdout[..i].contains(h).then_some(h))
    {
        return Err(FitError::invalid(
            "hold-out list",
            format!("{holdout:?}"),
            format!("distinct frame ids ({d} appears twice)"),
        ));
    }
    let mut base = capture.clone();
    for s in &mut base.sources {
        let p = Path::new(&s.path);
        if p.is_relative() {
            let abs = std::path::absolute(dir.join(p)).unwrap_or_else(|_| dir.join(p));
            s.path = abs.to_string_lossy().into_owned();
        }
    }
    let mut train = base.clone();
    train.frames.retain(|f| !holdout.contains(&f.id));
    let mut held = base;
    held.frames.retain(|f| holdout.contains(&f.id));
    if train.frames.is_empty() {
        return Err(FitError::invalid(
            "hold-out list",
            format!("{holdout:?}"),
            "at least one frame left to fit",
        ));
    }
    Ok((train, held))
}

/// Resample a frame onto the grid (linear RGB); `None` where the frame does not see
/// the pixel.
pub fn rectify(
    mapping: &PreparedMapping,
    img: &FrameImage,
    grid: &PlaneGrid,
) -> (ImageF32, Vec<bool>) {
    let lut = srgb8_to_linear_table();
    let (w, h, _) = img.shape();
    let mut out = ImageF32::new(grid.width, grid.height, 3);
    let mut mask = vec![false; grid.len()];
    let mut c = [0f32; 3];
    for r in 0..grid.height {
        let row = mapping.row(grid.pixel_centre(0, r).y);
        for col in 0..grid.width {
            let Some(p) = row.plane_to_pixel(grid.pixel_centre(col, r)) else {
                continue;
            };
            if !(p.x >= 0.0 && p.y >= 0.0 && p.x <= (w - 1) as f64 && p.y <= (h - 1) as f64) {
                continue;
            }
            img.sample_linear(p.x, p.y, &lut, &mut c);
            if c.iter().all(|v| v.is_finite()) {
                out.pixel_mut(col, r).copy_from_slice(&c);
                mask[r * grid.width + col] = true;
            }
        }
    }
    (out, mask)
}

/// Separable Gaussian blur (sigma 1.5, radius 5: the usual SSIM window) of one channel.
fn gauss(v: &[f64], w: usize, h: usize) -> Vec<f64> {
    let k: Vec<f64> = (-5i32..=5)
        .map(|i| (-(f64::from(i * i)) / (2.0 * 1.5 * 1.5)).exp())
        .collect();
    let pass = |src: &[f64], horizontal: bool| -> Vec<f64> {
        let mut out = vec![0.0; src.len()];
        for y in 0..h {
            for x in 0..w {
                let (mut s, mut ws) = (0.0, 0.0);
                for (t, kv) in k.iter().enumerate() {
                    let d = t as i64 - 5;
                    let (xx, yy) = if horizontal {
                        (x as i64 + d, y as i64)
                    } else {
                        (x as i64, y as i64 + d)
                    };
                    if xx < 0 || yy < 0 || xx >= w as i64 || yy >= h as i64 {
                        continue;
                    }
                    s += kv * src[yy as usize * w + xx as usize];
                    ws += kv;
                }
                out[y * w + x] = s / ws;
            }
        }
        out
    };
    pass(&pass(v, true), false)
}

/// Mean SSIM (Wang et al. 2004, Gaussian window, dynamic range 1) over the masked
/// pixels, averaged over channels.
pub fn ssim(a: &ImageF32, b: &ImageF32, mask: &[bool]) -> f64 {
    let (w, h) = (a.width, a.height);
    let (c1, c2) = (0.01f64.powi(2), 0.03f64.powi(2));
    let mut total = 0.0;
    for ch in 0..3 {
        let x: Vec<f64> = (0..w * h).map(|i| f64::from(a.data[i * 3 + ch])).collect();
        let y: Vec<f64> = (0..w * h).map(|i| f64::from(b.data[i * 3 + ch])).collect();
        let mx = gauss(&x, w, h);
        let my = gauss(&y, w, h);
        let xx = gauss(&x.iter().map(|v| v * v).collect::<Vec<_>>(), w, h);
        let yy = gauss(&y.iter().map(|v| v * v).collect::<Vec<_>>(), w, h);
        let xy = gauss(
            &x.iter().zip(&y).map(|(p, q)| p * q).collect::<Vec<_>>(),
            w,
            h,
        );
        let (mut s, mut n) = (0.0, 0usize);
        for i in 0..w * h {
            if !mask[i] {
                continue;
            }
            let (vx, vy, cxy) = (
                xx[i] - mx[i] * mx[i],
                yy[i] - my[i] * my[i],
                xy[i] - mx[i] * my[i],
            );
            s += ((2.0 * mx[i] * my[i] + c1) * (2.0 * cxy + c2))
                / ((mx[i] * mx[i] + my[i] * my[i] + c1) * (vx + vy + c2));
            n += 1;
        }
        total += if n > 0 { s / n as f64 } else { 0.0 };
    }
    total / 3.0
}

fn rmse(a: &ImageF32, b: &ImageF32, mask: &[bool]) -> (f64, f64) {
    let (mut se, mut sum, mut n) = (0.0, 0.0, 0usize);
    for (i, m) in mask.iter().enumerate() {
        if !m {
            continue;
        }
        for ch in 0..3 {
            let (x, y) = (f64::from(a.data[i * 3 + ch]), f64::from(b.data[i * 3 + ch]));
            se += (x - y).powi(2);
            sum += x;
            n += 1;
        }
    }
    let n = n.max(1) as f64;
    ((se / n).sqrt(), sum / n)
}

fn to_srgb(img: &ImageF32) -> ImageF32 {
    let mut out = img.clone();
    for v in &mut out.data {
        *v = linear_to_srgb(f64::from(*v).clamp(0.0, 1.0)) as f32;
    }
    out
}

/// Photo | rendering | 4 x |difference| side by side, block-averaged to at most
/// `max_tile` pixels on the long side; unseen pixels dark grey.
fn strip_image(photo: &ImageF32, ours: &ImageF32, mask: &[bool], max_tile: usize) -> ImageF32 {
    let (w, h) = (photo.width, photo.height);
    let d = w.max(h).div_ceil(max_tile.max(1)).max(1);
    let (tw, th) = (w.div_ceil(d), h.div_ceil(d));
    let gap = 4;
    let mut img = ImageF32::new(3 * tw + 4 * gap, th + 2 * gap, 3);
    img.data.fill(1.0);
    for ty in 0..th {
        for tx in 0..tw {
            let mut acc = [0.0f64; 7];
            for y in ty * d..((ty + 1) * d).min(h) {
                for x in tx * d..((tx + 1) * d).min(w) {
                    let i = y * w + x;
                    if !mask[i] {
                        continue;
                    }
                    for ch in 0..3 {
                        acc[ch] += f64::from(photo.data[i * 3 + ch]);
                        acc[3 + ch] += f64::from(ours.data[i * 3 + ch]);
                    }
                    acc[6] += 1.0;
                }
            }
            for (k, off) in [(0usize, 0usize), (1, 3), (2, 9)] {
                let p = img.pixel_mut(gap + k * (tw + gap) + tx, gap + ty);
                for ch in 0..3 {
                    p[ch] = if acc[6] == 0.0 {
                        0.05
                    } else if off == 9 {
                        (4.0 * (acc[ch] - acc[3 + ch]).abs() / acc[6]) as f32
                    } else {
                        (acc[off + ch] / acc[6]) as f32
                    };
                }
            }
        }
    }
    img
}

/// Settings of [`evaluate_holdout`].
#[derive(Debug, Clone, PartialEq)]
pub struct HoldoutConfig {
    /// Frame ids to hold out.
    pub holdout: Vec<u32>,
    /// The fit (its `diffuse_only` gives the Lambertian baseline).
    pub fit: FitConfig,
    /// Long side of each tile of the strips, pixels.
    pub strip_px: usize,
}

/// Fit `capture_dir` without the held-out frames into `out/maps`, render the held-out
/// frames and write `out/eval/eval.json` and the strips. `out` is built under a
/// temporary name and renamed when complete. Returns the figures, the folder and the
/// fitted maps (for a report, without reading them again).
pub fn evaluate_holdout(
    capture_dir: &Path,
    out: &Path,
    overwrite: bool,
    cfg: &HoldoutConfig,
    source: &dyn FrameSource,
    flip: Option<&dyn ImageMetric>,
    progress: &dyn Progress,
) -> Result<(HoldoutReport, PathBuf, crate::output::LoadedMaps), FitError> {
    cfg.fit.validate()?;
    let (capture, dir) = RegisteredCapture::load_with_folder(capture_dir)?;
    let (train, held) = split(&capture, &dir, &cfg.holdout)?;
    let staging = svbrdf_core::fsutil::StagingDir::new(out, overwrite, &capture.input_paths(&dir))?;
    let root = staging.path().to_path_buf();
    let train_dir = root.join("train");
    std::fs::create_dir_all(&train_dir).map_err(|e| CoreError::io(&train_dir, e))?;
    train.save(&train_dir)?;
    let t = std::time::Instant::now();
    let fitted = crate::run(
        &train_dir,
        &root.join("maps"),
        true,
        &cfg.fit,
        source,
        progress,
    )?;
    let fit_seconds = t.elapsed().as_secs_f64();
    let maps = crate::output::read_maps(&fitted.out)?;
    let intensity = maps.manifest.summary.light_intensity;
    let ambient = maps
        .manifest
        .summary
        .room_light
        .filter(|r| r.applied)
        .map_or(0.0, |r| r.ambient);
    let model = cfg.fit.model.model();
    let eval_dir = root.join(EVAL_DIR);
    std::fs::create_dir_all(&eval_dir).map_err(|e| CoreError::io(&eval_dir, e))?;
    let mut images = Vec::new();
    progress.stage("held-out frames", held.frames.len() as u64);
    source.decode(&held, &dir, &mut |k, img| {
        let f = &held.frames[k];
        let mapping = PreparedMapping::new(f)?;
        let (photo, mask) = rectify(&mapping, &img, &maps.grid);
        // The held-out frame's own exposure scales what it shows, and it was taken in
        // the same room: the fit's room light is part of the prediction.
        let ours = relight_in_room(
            &maps.grid,
            &maps.params,
            model,
            intensity.map(|i| i * f.gain()),
            Vec3::from(f.light_position),
            Vec3::from(f.camera_position),
            ambient,
        );
        let (rl_raw, mean) = rmse(&photo, &ours, &mask);
        let mut ours = ours;
        for v in &mut ours.data {
            *v = v.min(RECORDED_MAX);
        }
        let (rl, _) = rmse(&photo, &ours, &mask);
        let (ps, os) = (to_srgb(&photo), to_srgb(&ours));
        let (rs, _) = rmse(&ps, &os, &mask);
        let flip = match flip {
            Some(m) => Some(m.mean_error(&ps, &os, &mask)?),
            None => None,
        };
        let name = f
            .image
            .clone()
            .or_else(|| f.frame_index.map(|i| format!("frame {i}")))
            .unwrap_or_else(|| format!("frame id {}", f.id));
        let strip = format!("strip_{:03}.png", f.id);
        write_png(
            &eval_dir.join(&strip),
            &strip_image(&photo, &ours, &mask, cfg.strip_px),
            Encoding::Srgb,
            PngDepth::Eight,
            &[
                ("map", "photo | rendering | 4x abs difference".into()),
                ("frame", name.clone()),
            ],
        )?;
        images.push(HoldoutError {
            id: f.id,
            name,
            camera_position: f.camera_position,
            light_position: f.light_position,
            pixels: mask.iter().filter(|m| **m).count(),
            rmse_linear: rl,
            relative_rmse_linear: if mean > 0.0 { rl / mean } else { 0.0 },
            rmse_linear_unclipped: rl_raw,
            relative_rmse_linear_unclipped: if mean > 0.0 { rl_raw / mean } else { 0.0 },
            rmse_srgb: rs,
            ssim_linear: ssim(&photo, &ours, &mask),
            ssim_srgb: ssim(&ps, &os, &mask),
            strip,
            flip,
        });
        progress.advance(1);
        Ok(())
    })?;
    progress.finish();
    images.sort_by_key(|e| e.id);
    let report = HoldoutReport {
        holdout: cfg.holdout.clone(),
        fitted_frames: train.frames.len(),
        model: cfg.fit.model.model().name().to_string(),
        diffuse_only: cfg.fit.diffuse_only,
        mean: MeanErrors::of(&images),
        images,
        fit_seconds,
        flip_metric: flip.map(|m| m.describe()),
    };
    svbrdf_core::fsutil::write_json(&eval_dir.join(EVAL_FILE), &report)?;
    let out = staging.commit()?;
    Ok((report, out, maps))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ssim_is_one_for_equal_images_and_drops_with_noise() {
        let mut a = ImageF32::new(24, 20, 3);
        for (i, v) in a.data.iter_mut().enumerate() {
            *v = ((i * 37) % 101) as f32 / 101.0;
        }
        let mask = vec![true; 24 * 20];
        assert!((ssim(&a, &a, &mask) - 1.0).abs() < 1e-9);
        let mut b = a.clone();
        for (i, v) in b.data.iter_mut().enumerate() {
            *v += if i % 2 == 0 { 0.2 } else { -0.2 };
        }
        let s = ssim(&a, &b, &mask);
        assert!(s < 0.9 && s > -1.0, "{s}");
        let (r, _) = rmse(&a, &b, &mask);
        assert!((r - 0.2).abs() < 1e-6);
    }
}
