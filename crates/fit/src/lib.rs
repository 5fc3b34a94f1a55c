//! # svbrdf-fit
//!
//! The appearance stage (paper section 3.2): from a registered capture's observations
//! to spatially varying BRDF maps. Pure Rust; frames arrive already decoded (the
//! binary decodes them through `svbrdf-cv`), so this crate builds and tests without
//! OpenCV.
//!
//! Steps: [`observations`] (per-pixel linear colours, streamed frame by frame),
//! [`cluster`] (k-means++ on average colour in L*a*b*, elbow choice of k), [`tree`]
//! (recursive constrained fitting with the redundant-observation binning),
//! per-pixel refinement of diffuse albedo and normal, [`render`] (re-rendering check,
//! relighting) and [`output`] (maps as EXR and PNG with a JSON manifest).
#![deny(missing_docs)]
// Per-channel and per-parameter loops index several parallel arrays at once; iterator
// chains over three of them read worse than the index.
#![allow(clippy::needless_range_loop)]

pub mod cluster;
mod colours;
pub mod confidence;
pub mod config;
pub mod evaluate;
pub mod fast;
pub mod holdout;
mod intensity;
mod neighbour;
pub mod observations;
pub mod output;
mod reassign;
mod refine;
pub mod render;
mod resources;
pub mod room;
pub mod sample_batch;
pub mod select;
pub mod solver;
mod stages;
mod summary;
pub mod tree;
mod turn;

use std::time::Instant;

use svbrdf_core::capture::RegisteredCapture;
use svbrdf_core::progress::Progress;
use svbrdf_core::CoreError;

pub use config::{FitConfig, RoomLightMode};
pub use intensity::light_intensity;
pub use observations::{ObservationBuilder, Observations};
use refine::refine;
pub(crate) use refine::BATCH;
pub use resources::{available_memory_bytes, estimated_fit_bytes, output_grid, MAX_GRID_PIXELS};
pub use summary::{ClusterInfo, FitSummary, FittedMaps, IntensitySource, TurnedGrain, TURNED_DEG};

pub(crate) use stages::fit_once;

/// Errors of the appearance stage.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FitError {
    /// From the core (files, formats, invalid values).
    #[error(transparent)]
    Core(#[from] CoreError),
    /// Nothing to fit.
    #[error("{0}")]
    NoData(String),
    /// The frame source (video decoder, image reader) failed.
    #[error("{0}")]
    Source(String),
}

/// Supplies the decoded frames of a capture (the binary implements it with OpenCV's
/// video decoder; tests can feed images directly).
pub trait FrameSource {
    /// Call `sink(k, linear_rgb)` for every frame `k` of `capture.frames`; `dir` holds
    /// `capture.json`.
    fn decode(
        &self,
        capture: &RegisteredCapture,
        dir: &std::path::Path,
        sink: &mut dyn FnMut(usize, svbrdf_core::image::FrameImage) -> Result<(), FitError>,
    ) -> Result<(), FitError>;
}

/// What [`run`] wrote.
#[derive(Debug, Clone)]
pub struct FitRun {
    /// The output folder.
    pub out: std::path::PathBuf,
    /// Its manifest.
    pub manifest: output::FitManifest,
}

/// The whole stage: read the registered capture in `capture_dir`, gather observations
/// frame by frame, fit, and write the output folder `out` (built under a temporary
/// name and renamed when complete).
pub fn run(
    capture_dir: &std::path::Path,
    out: &std::path::Path,
    overwrite: bool,
    cfg: &FitConfig,
    source: &dyn FrameSource,
    progress: &dyn Progress,
) -> Result<FitRun, FitError> {
    cfg.validate()?;
    let (capture, dir) = RegisteredCapture::load_with_folder(capture_dir)?;
    if capture.frames.is_empty() {
        return Err(FitError::NoData(format!(
            "{}: the capture has no frames",
            capture_dir.display()
        )));
    }
    let grid = output_grid(&capture, cfg)?;
    let staging = svbrdf_core::fsutil::StagingDir::new(out, overwrite, &capture.input_paths(&dir))?;
    let t = Instant::now();
    progress.stage("observations", capture.frames.len() as u64);
    let mut builder = ObservationBuilder::new(&capture, grid, cfg)?;
    let mut sampling = 0.0;
    source.decode(&capture, &dir, &mut |k, img| {
        let t = Instant::now();
        builder.add_frame(k, &img)?;
        sampling += t.elapsed().as_secs_f64();
        progress.advance(1);
        Ok(())
    })?;
    let mut obs = builder.finish();
    progress.finish();
    let t_obs = t.elapsed().as_secs_f64();
    let (maps, mut summary) = fit(&mut obs, &capture, cfg, progress)?;
    summary
        .timings
        .insert(0, ("observations: sampling frames".into(), sampling));
    summary.timings.insert(
        0,
        ("observations: decoding frames".into(), t_obs - sampling),
    );
    let nf = obs.frames.len();
    let n = cfg.strip_frames.clamp(1, nf);
    let chosen: Vec<usize> = (0..n)
        .map(|i| {
            if n == 1 {
                nf / 2
            } else {
                i * (nf - 1) / (n - 1)
            }
        })
        .collect();
    let strip = render::strip(
        &obs,
        &maps.params,
        cfg.model.model(),
        summary.light_intensity,
        &chosen,
        512,
    );
    let manifest = output::write_outputs(staging.path(), &maps, &summary, &strip)?;
    let out = staging.commit()?;
    Ok(FitRun { out, manifest })
}

impl FitError {
    /// An out-of-range value (see [`CoreError::invalid`]).
    pub fn invalid(
        what: impl Into<String>,
        value: impl ToString,
        expected: impl Into<String>,
    ) -> Self {
        Self::Core(CoreError::invalid(what, value, expected))
    }
}

/// Above this share of the observed surface whose highlight was never seen, the fit
/// warns.
pub const SPECULAR_UNSEEN_WARNING: f64 = 0.25;

/// Above this share of the observations near the mirror direction with a clipped
/// channel, the fit warns that the highlights' peaks are lower bounds. Measured on the
/// `paper` preset (true registration): 8-bit SDR clips 49% there and the brushed
/// metal's highlight under held-out light 1 renders at 0.73-0.78 of the truth (its
/// fitted peak `rho_s / (alpha_x alpha_y)` 0.77-0.79 of the truth's, relighting 117-127%
/// at 1 mm); 10-bit HLG of the same rendering clips 6% and halves that error.
pub const CLIPPED_PEAK_WARNING: f64 = 0.3;

/// With an unknown intensity, the brightest initial cluster's `rho_d + rho_s` is kept
/// at or below this.
const ENERGY_MARGIN: f64 = 0.95;

/// Fit maps to observations. `progress` sees the validation, clustering, fitting and
/// refinement. With `select_folds` > 0 the settings are first chosen by how well they
/// predict held-out frames ([`select`]), and the record lands in the summary. The room
/// light found (`room_light`) is left in `obs.ambient`.
pub fn fit(
    obs: &mut Observations,
    capture: &RegisteredCapture,
    cfg: &FitConfig,
    progress: &dyn Progress,
) -> Result<(FittedMaps, FitSummary), FitError> {
    cfg.validate()?;
    // The estimate reads the observations under no room light, whatever an earlier
    // fit of the same observations left in them.
    obs.ambient = 0.0;
    let t = Instant::now();
    let room = stages::room_light(obs, capture, cfg)?;
    obs.ambient = room.filter(|r| r.applied).map_or(0.0, |r| r.ambient);
    let t_room = t.elapsed().as_secs_f64();
    let obs = &*obs;
    let (maps, mut summary) = match select::select(obs, capture, cfg, progress)? {
        None => fit_once(obs, capture, cfg, progress)?,
        Some((chosen, record)) => {
            let (maps, mut summary) = fit_once(obs, capture, &chosen, progress)?;
            summary
                .timings
                .insert(0, ("choosing settings".to_string(), record.seconds));
            summary.selection = Some(record);
            (maps, summary)
        }
    };
    if let Some(r) = &room {
        summary
            .timings
            .insert(0, ("room light".to_string(), t_room));
        summary.warnings.extend(r.warning());
    }
    summary.room_light = room;
    Ok((maps, summary))
}

/// Half-vector angle from the plane's normal within which an observation counts as
/// near the mirror direction, degrees.
pub const NEAR_MIRROR_DEG: f64 = 4.0;

#[cfg(test)]
mod tests {
    use super::*;
    use svbrdf_core::brdf::{BrdfModel, BrdfParams, Prepared, Ward};
    use svbrdf_core::geometry::Vec3;
    use svbrdf_core::plane::PlaneGrid;
    use svbrdf_core::plane::Region;
    use svbrdf_core::progress::NoProgress;

    /// Two materials (left half matte red, right half shiny blue) observed by a
    /// flash camera sweeping over the plane; observations rendered exactly with Ward.
    fn two_materials() -> (Observations, RegisteredCapture, [BrdfParams; 2]) {
        two_materials_rendered(true, 100.0)
    }

    /// [`two_materials`] under a light of `intensity`, its clipped observations dropped
    /// or kept as censored values.
    fn two_materials_rendered(
        drop_clipped: bool,
        intensity: f64,
    ) -> (Observations, RegisteredCapture, [BrdfParams; 2]) {
        two_materials_in_room(drop_clipped, intensity, 0.0)
    }

    /// [`two_materials_rendered`] with room light `ambient` in every frame.
    fn two_materials_in_room(
        drop_clipped: bool,
        intensity: f64,
        ambient: f64,
    ) -> (Observations, RegisteredCapture, [BrdfParams; 2]) {
        let truth = [
            BrdfParams {
                rho_d: [0.6, 0.15, 0.1],
                rho_s: [0.03; 3],
                alpha_x: 0.3,
                alpha_y: 0.3,
                ..BrdfParams::default()
            },
            BrdfParams {
                rho_d: [0.05, 0.1, 0.4],
                rho_s: [0.3, 0.3, 0.3],
                alpha_x: 0.12,
                alpha_y: 0.2,
                ..BrdfParams::default()
            },
        ];
        let region = Region::centred(4.0, 4.0);
        let grid = PlaneGrid::new(region, 10.0).unwrap();
        let mut frames = Vec::new();
        for i in 0..25 {
            let (u, v) = ((i % 5) as f64 - 2.0, (i / 5) as f64 - 2.0);
            let camera = Vec3::new(1.5 * u, 1.5 * v, 9.0 + 0.3 * i as f64 % 3.0);
            frames.push(observations::FrameGeometry {
                id: i,
                camera,
                light: camera + Vec3::new(1.4, -0.3, 0.0),
                gain: 1.0,
            });
        }
        let obs = observations::rendered_in_room(
            grid,
            frames,
            |px| truth[usize::from(grid.pixel_centre(px % grid.width, px / grid.width).x > 0.0)],
            intensity,
            drop_clipped,
            ambient,
        );
        let mut cap = RegisteredCapture::new("test", region, 10.0);
        cap.light_intensity = Some([intensity; 3]);
        // A flash video, as the room light's `auto` wants.
        cap.sources.push(svbrdf_core::capture::Source {
            kind: svbrdf_core::capture::SourceKind::Video,
            path: "flash.mp4".into(),
            encoding: svbrdf_core::maps::Encoding::Srgb,
            stream: 0,
            video: None,
        });
        (obs, cap, truth)
    }

    /// What the validation's shared cluster trees rely on (`select`): a candidate that
    /// changes only the per-pixel refinement, fitted from the defaults' tree, gives the
    /// parameters of its own whole fit, and the defaults' parameters before the
    /// per-pixel specular step are the fit with `refine_specular` off.
    #[test]
    fn refinement_only_settings_fitted_from_a_shared_tree_equal_whole_fits() {
        let (obs, cap, _) = two_materials();
        let base = FitConfig {
            select_folds: 0,
            ..FitConfig::default()
        };
        let tree = stages::fit_tree(&obs, &cap, &base, &NoProgress).unwrap();
        let refined =
            stages::refine_stage(&obs, &tree, tree.params.clone(), &base, &NoProgress, true);
        let whole = |c: &FitConfig| fit_once(&obs, &cap, c, &NoProgress).unwrap().0.params;
        assert_eq!(refined.params, whole(&base));
        let strong = FitConfig {
            refine_prior: base.refine_prior * 8.0,
            ..base.clone()
        };
        let from_tree = stages::refine_stage(
            &obs,
            &tree,
            tree.params.clone(),
            &strong,
            &NoProgress,
            false,
        )
        .params;
        assert_eq!(from_tree, whole(&strong));
        assert_ne!(from_tree, refined.params, "the prior changes nothing here");
        let cluster_lobes = FitConfig {
            refine_specular: false,
            ..base.clone()
        };
        let before = refined.before_specular.unwrap();
        assert_eq!(before, whole(&cluster_lobes));
        assert_ne!(
            before, refined.params,
            "no pixel got a lobe of its own here"
        );
    }

    #[test]
    fn clipped_highlight_peaks_are_said_to_be_lower_bounds() {
        let cfg = FitConfig {
            select_folds: 0,
            ..FitConfig::default()
        };
        let said = |s: &FitSummary| s.warnings.iter().any(|w| w.contains("mirror direction"));
        // The shiny material's peaks clip (as observations dropped: nothing near the
        // mirror direction is left clipped).
        let (obs, cap, _) = two_materials_rendered(true, 160.0);
        let (_, s) = fit(&mut obs.clone(), &cap, &cfg, &NoProgress).unwrap();
        assert!(!said(&s), "{:?}", s.warnings);
        // Kept as lower bounds: most of the shiny half's observations near its mirror
        // direction are clipped (none of the matte half's).
        let (obs, cap, _) = two_materials_rendered(false, 160.0);
        let (_, s) = fit(&mut obs.clone(), &cap, &cfg, &NoProgress).unwrap();
        assert!(
            s.clipped_near_mirror
                .is_some_and(|c| c > CLIPPED_PEAK_WARNING),
            "{s:?}"
        );
        assert!(said(&s), "{:?}", s.warnings);
    }

    #[test]
    fn recovers_two_materials_and_respects_the_minimum_cluster_size() {
        let (mut obs, cap, truth) = two_materials();
        let cfg = FitConfig {
            refine: false,
            ..FitConfig::default()
        };
        let (maps, summary) = fit(&mut obs, &cap, &cfg, &NoProgress).unwrap();
        // Average colour varies inside each material (falloff, highlights), so the
        // elbow may pick more than two clusters, but no cluster mixes the materials.
        assert!(summary.initial_clusters >= 2, "{:?}", summary.kmeans_sse);
        let mut side = vec![[false; 2]; maps.clusters.len()];
        for (px, c) in maps.cluster.iter().enumerate() {
            side[*c as usize][usize::from(px % 40 >= 20)] = true;
        }
        assert!(
            side.iter().all(|s| !(s[0] && s[1])),
            "a cluster mixes both materials"
        );
        assert!(maps.clusters.iter().all(|c| c.pixels >= cfg.min_cluster_px));
        // Exact data: the fit reproduces it almost exactly...
        assert!(
            summary.rmse_clusters < 2e-3,
            "rmse {}",
            summary.rmse_clusters
        );
        // ...and finds each material's parameters.
        for (px, t) in [(5 * 40 + 5, truth[0]), (30 * 40 + 35, truth[1])] {
            let p = maps.params[px];
            for c in 0..3 {
                assert!((p.rho_d[c] - t.rho_d[c]).abs() < 0.01, "{p:?} vs {t:?}");
                assert!((p.rho_s[c] - t.rho_s[c]).abs() < 0.03, "{p:?} vs {t:?}");
            }
            assert!((p.alpha_x - t.alpha_x).abs() < 0.03, "{p:?} vs {t:?}");
            assert!((p.alpha_y - t.alpha_y).abs() < 0.03, "{p:?} vs {t:?}");
            assert!(p.normal().z > 0.999);
        }
        assert!(maps.params.iter().all(BrdfParams::is_physical));
    }

    /// Room light at about 14% of the flash's diffuse light: found, fitted with every
    /// observation and kept out of the maps; the paper's model (`room_light` off) reads
    /// it as albedo. Without room light none is found.
    #[test]
    fn room_light_is_found_and_kept_out_of_the_albedo() {
        let ambient = 0.0012;
        let cfg = FitConfig {
            refine: false,
            select_folds: 0,
            room_light: RoomLightMode::On,
            ..FitConfig::default()
        };
        let (mut obs, cap, truth) = two_materials_in_room(true, 100.0, ambient);
        let (maps, summary) = fit(&mut obs, &cap, &cfg, &NoProgress).unwrap();
        let room = summary.room_light.expect("an estimate");
        assert!(
            (room.ambient - ambient).abs() < 0.15 * ambient,
            "{room:?} against {ambient}"
        );
        assert!(
            room.share_of_flash > 0.08 && room.share_of_flash < 0.2,
            "{room:?}"
        );
        assert!(room.residual_drop > 0.0, "{room:?}");
        let off = FitConfig {
            room_light: RoomLightMode::Off,
            ..cfg.clone()
        };
        let (mut obs_off, ..) = two_materials_in_room(true, 100.0, ambient);
        let (paper, paper_summary) = fit(&mut obs_off, &cap, &off, &NoProgress).unwrap();
        assert!(paper_summary.room_light.is_none());
        let px = 5 * 40 + 5;
        for c in 0..3 {
            let (t, ours, theirs) = (
                truth[0].rho_d[c],
                maps.params[px].rho_d[c],
                paper.params[px].rho_d[c],
            );
            assert!(
                (ours - t).abs() < 0.03 * t + 0.005,
                "channel {c}: {ours} vs {t}"
            );
            assert!(
                theirs > 1.05 * t,
                "channel {c}: the paper's model {theirs} vs {t}"
            );
        }
        let (mut dark, ..) = two_materials_in_room(true, 100.0, 0.0);
        let (_, s) = fit(&mut dark, &cap, &cfg, &NoProgress).unwrap();
        let none = s.room_light.expect("an estimate");
        assert!(none.share_of_flash <= 0.01, "{none:?}");
    }

    /// Room light brighter than the flash's light on the surface puts the estimate at
    /// the top of the range searched: `auto` does not apply it and warns, `on` does.
    #[test]
    fn a_room_light_at_the_top_of_the_range_is_not_applied() {
        let run = |mode: RoomLightMode| {
            let (mut obs, cap, _) = two_materials_in_room(true, 100.0, 0.03);
            let cfg = FitConfig {
                refine: false,
                select_folds: 0,
                room_light: mode,
                ..FitConfig::default()
            };
            let (_, s) = fit(&mut obs, &cap, &cfg, &NoProgress).unwrap();
            (s, obs.ambient)
        };
        let (auto, ambient) = run(RoomLightMode::Auto);
        let room = auto.room_light.expect("an estimate");
        assert!(
            room.share_of_flash >= room::MAX_SHARE && !room.applied,
            "{room:?}"
        );
        assert_eq!(ambient, 0.0);
        assert!(
            auto.warnings
                .iter()
                .any(|w| w.contains("could not be told from the material")),
            "{:?}",
            auto.warnings
        );
        let (on, ambient) = run(RoomLightMode::On);
        assert!(on.room_light.is_some_and(|r| r.applied));
        assert!(ambient > 0.0);
        assert!(on.warnings.iter().any(|w| w.contains("was applied")));
    }

    /// `auto` leaves photo sets (image sources) to the paper's model; `on` estimates.
    #[test]
    fn photo_sets_get_room_light_only_when_asked() {
        let run = |mode: RoomLightMode| {
            let (mut obs, mut cap, _) = two_materials_in_room(true, 100.0, 0.0012);
            cap.sources[0].kind = svbrdf_core::capture::SourceKind::Images;
            let cfg = FitConfig {
                refine: false,
                select_folds: 0,
                room_light: mode,
                ..FitConfig::default()
            };
            fit(&mut obs, &cap, &cfg, &NoProgress).unwrap().1.room_light
        };
        assert!(run(RoomLightMode::Auto).is_none());
        assert!(run(RoomLightMode::On).is_some_and(|r| r.applied));
    }

    #[test]
    fn rerender_check_keeps_pixels_in_grid_order() {
        let (obs, _, truth) = two_materials();
        // Wrong on purpose on the right half, so residuals differ by pixel.
        let params: Vec<BrdfParams> = (0..obs.pixels())
            .map(|p| truth[usize::from(p % 40 >= 20)])
            .collect();
        let mut off = params.clone();
        for (p, q) in off.iter_mut().enumerate() {
            q.rho_d[0] *= 1.0 + (p % 7) as f64 * 0.05;
        }
        let (res, frames) = render::rerender_check(&obs, &off, &Ward, [100.0; 3]);
        assert_eq!(res.len(), obs.pixels());
        for px in [0, 17, 40 * 13 + 5, 40 * 39 + 39] {
            let prep = Prepared::new(off[px]);
            let mut s = 0.0;
            for o in obs.range(px) {
                let v = Ward.radiance(&prep, &obs.light_view(px, o), 100.0);
                let c = obs.color(o);
                s += (0..3).map(|k| (v[k] - c[k]).powi(2)).sum::<f64>();
            }
            let want = (s / (3 * obs.count(px)) as f64).sqrt();
            assert!((f64::from(res[px]) - want).abs() < 1e-6, "pixel {px}");
        }
        assert_eq!(
            frames.iter().map(|f| f.observations).sum::<usize>(),
            obs.len()
        );
        let (exact, _) = render::rerender_check(&obs, &params, &Ward, [100.0; 3]);
        assert!(exact.iter().all(|r| *r < 1e-4));
    }

    #[test]
    fn refinement_recovers_a_per_pixel_albedo_step_inside_a_cluster() {
        let (mut obs, cap, _) = two_materials();
        // Darken one pixel of the matte half by 20%: too small to be its own cluster.
        let px = 12 * 40 + 8;
        for o in obs.range(px) {
            obs.rgb[o] = obs.rgb[o].map(|v| (f64::from(v) * 0.8) as u16);
        }
        let cfg = FitConfig::default();
        let (maps, _) = fit(&mut obs.clone(), &cap, &cfg, &NoProgress).unwrap();
        let ratio = maps.params[px].rho_d[0] / maps.params[px + 1].rho_d[0];
        assert!((ratio - 0.8).abs() < 0.05, "ratio {ratio}");
    }

    /// Drops the observations whose `keep` is false.
    fn keep_only(obs: &mut Observations, keep: &[bool]) {
        let mut start = vec![0];
        let (mut f, mut r, mut k) = (Vec::new(), Vec::new(), Vec::new());
        for px in 0..obs.pixels() {
            for o in obs.range(px).filter(|o| keep[*o]) {
                f.push(obs.frame[o]);
                r.push(obs.rgb[o]);
                k.push(obs.key[o]);
            }
            start.push(f.len());
        }
        (obs.start, obs.frame, obs.rgb, obs.key) = (start, f, r, k);
    }

    /// The 2 x 2 patch of [`two_materials`]' shiny half that the per-pixel lobe tests
    /// make glossier than its cluster (around x 0.7, y -0.15 cm).
    fn glossier_patch() -> Vec<usize> {
        [(26, 21), (27, 21), (26, 22), (27, 22)]
            .iter()
            .map(|(x, y)| y * 40 + x)
            .collect()
    }

    /// Fits of `obs` (no choice of settings) with every pixel on its cluster's lobe, and
    /// with `refine_specular`.
    fn without_and_with_own_lobes(
        obs: &Observations,
        cap: &RegisteredCapture,
    ) -> ((FittedMaps, FitSummary), (FittedMaps, FitSummary)) {
        let base = FitConfig {
            select_folds: 0,
            refine_specular: false,
            ..FitConfig::default()
        };
        let cfg = FitConfig {
            refine_specular: true,
            ..base.clone()
        };
        let plain = fit(&mut obs.clone(), cap, &base, &NoProgress).unwrap();
        let own = fit(&mut obs.clone(), cap, &cfg, &NoProgress).unwrap();
        (plain, own)
    }

    #[test]
    fn pixels_whose_peak_was_seen_get_their_own_lobe_with_refine_specular() {
        let (mut obs, cap, truth) = two_materials();
        // A 2 x 2 patch of the shiny half reflects 40% more specular light: too small
        // to be its own cluster, so only a per-pixel lobe can follow it. It lies where
        // the camera above the centre sees its highlight (x 0.7, y -0.15 cm).
        let patch = glossier_patch();
        let brighter = BrdfParams {
            rho_s: [0.42; 3],
            ..truth[1]
        };
        for &px in &patch {
            let prep = Prepared::new(brighter);
            for o in obs.range(px) {
                let v = Ward.radiance(&prep, &obs.light_view(px, o), 100.0);
                if obs.clipped(o).iter().all(|c| !c) {
                    obs.rgb[o] = v.map(|x| (x * observations::RGB_SCALE).round() as u16);
                }
            }
        }
        let ((plain, plain_summary), (own, summary)) = without_and_with_own_lobes(&obs, &cap);
        assert_eq!(plain_summary.pixel_lobes, 0);
        assert!(summary.pixel_lobes > 0);
        let seen: Vec<usize> = patch
            .iter()
            .copied()
            .filter(|&p| confidence::peak_seen(&obs, p, &own.params[p]))
            .collect();
        assert!(!seen.is_empty(), "no patch pixel saw its peak");
        for &px in &seen {
            let (a, b) = (plain.params[px].rho_s[1], own.params[px].rho_s[1]);
            eprintln!("pixel {px}: cluster lobe {a:.3}, own {b:.3}");
            assert!(
                (b - 0.42).abs() < 0.5 * (a - 0.42).abs(),
                "pixel {px}: cluster lobe {a}, own lobe {b}, truth 0.42"
            );
        }
        // A pixel whose lobe its observations do not measure keeps its cluster's lobe.
        let unseen = (0..obs.pixels())
            .find(|&p| obs.count(p) > 0 && !confidence::lobe_measured(&obs, p, &own.params[p]));
        if let Some(p) = unseen {
            assert_eq!(own.params[p].rho_s, plain.params[p].rho_s, "pixel {p}");
        }
        assert!(own.params.iter().all(BrdfParams::is_physical));
    }

    #[test]
    fn a_clipped_peak_is_measured_from_its_flank() {
        // Under a light bright enough to clip the shiny half's peak in every frame near
        // its mirror direction (censored observations), a 2 x 2 patch reflecting 40%
        // more specular light: no pixel sees its peak unclipped, but the flank's
        // fall-off measures the lobe, so the patch gets lobes of its own.
        const LIGHT: f64 = 300.0;
        let (mut obs, cap, truth) = two_materials_rendered(false, LIGHT);
        let patch = glossier_patch();
        let brighter = BrdfParams {
            rho_s: [0.42; 3],
            ..truth[1]
        };
        let sat = obs.saturation;
        for &px in &patch {
            let prep = Prepared::new(brighter);
            for o in obs.range(px) {
                let v = Ward.radiance(&prep, &obs.light_view(px, o), LIGHT);
                obs.rgb[o] = v.map(|x| {
                    if x >= sat {
                        observations::CLIPPED
                    } else {
                        (x * observations::RGB_SCALE).round() as u16
                    }
                });
            }
        }
        let clipped_peak: Vec<usize> = patch
            .iter()
            .copied()
            .filter(|&p| {
                !confidence::peak_seen(&obs, p, &brighter)
                    && confidence::lobe_measured(&obs, p, &brighter)
                    && obs.range(p).any(|o| obs.clipped(o).iter().all(|&c| c))
            })
            .collect();
        assert!(
            !clipped_peak.is_empty(),
            "no patch pixel has a clipped peak and a measured flank"
        );
        // Seen by fewer frames, the same flank gives no lobe of its own: keep each patch
        // pixel's brightest observations (the clipped peak and the flank), one short of
        // `FLANK_MIN_VIEWS`, then one more.
        for views in [confidence::FLANK_MIN_VIEWS - 1, confidence::FLANK_MIN_VIEWS] {
            let mut fewer = obs.clone();
            let mut keep = vec![true; fewer.len()];
            for &p in &clipped_peak {
                let mut by_value: Vec<usize> = fewer.range(p).collect();
                by_value.sort_by_key(|&o| std::cmp::Reverse(fewer.rgb[o][1]));
                for &o in &by_value[views..] {
                    keep[o] = false;
                }
            }
            keep_only(&mut fewer, &keep);
            for &p in &clipped_peak {
                assert_eq!(
                    confidence::lobe_measured(&fewer, p, &brighter),
                    views >= confidence::FLANK_MIN_VIEWS,
                    "pixel {p} seen {views} times"
                );
            }
        }
        let ((plain, _), (own, summary)) = without_and_with_own_lobes(&obs, &cap);
        assert!(summary.pixel_lobes > 0);
        let peak = |p: &BrdfParams| p.rho_s[1] / (p.alpha_x * p.alpha_y);
        let truth_peak = peak(&brighter);
        for &px in &clipped_peak {
            let (a, b) = (peak(&plain.params[px]), peak(&own.params[px]));
            eprintln!(
                "pixel {px}: peak of the cluster lobe {a:.2}, own {b:.2}, truth {truth_peak:.2}"
            );
            assert!(
                (b - truth_peak).abs() < 0.6 * (a - truth_peak).abs(),
                "pixel {px}: peak of the cluster lobe {a}, own {b}, truth {truth_peak}"
            );
        }
        assert!(own.params.iter().all(BrdfParams::is_physical));
    }

    #[test]
    fn unobserved_pixels_get_a_neighbours_cluster_and_no_nan() {
        let (mut obs, cap, _) = two_materials();
        // Remove every observation of a 3x3 block.
        let mut keep = vec![true; obs.len()];
        for y in 10..13 {
            for x in 10..13 {
                for o in obs.range(y * 40 + x) {
                    keep[o] = false;
                }
            }
        }
        keep_only(&mut obs, &keep);
        let (maps, summary) =
            fit(&mut obs.clone(), &cap, &FitConfig::default(), &NoProgress).unwrap();
        assert_eq!(summary.covered_pixels, 40 * 40 - 9);
        assert_eq!(maps.coverage[11 * 40 + 11], 0);
        assert_eq!(maps.cluster[11 * 40 + 11], maps.cluster[11 * 40 + 9]);
        assert!(maps.params.iter().all(BrdfParams::is_physical));
    }
}
