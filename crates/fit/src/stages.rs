//! The fit's stages with the settings as given: the cluster tree ([`fit_tree`]), the
//! per-pixel refinement ([`refine_stage`]) and the records ([`finish`]). They are
//! separate so that the held-out validation (`select`) can fit the cluster tree once
//! for every candidate setting that differs only in the per-pixel refinement.

use std::time::Instant;

use rayon::prelude::*;
use svbrdf_core::brdf::{BrdfParams, ModelKind};
use svbrdf_core::capture::RegisteredCapture;
use svbrdf_core::progress::Progress;

use crate::config::ClusterColour;
use crate::room::RoomLight;
use crate::solver::Freedom;
use crate::tree::Context;
use crate::{
    cluster, confidence, light_intensity, neighbour, refine, render, summary, tree, ClusterInfo,
    FitConfig, FitError, FitSummary, FittedMaps, IntensitySource, Observations, RoomLightMode,
    CLIPPED_PEAK_WARNING, ENERGY_MARGIN, NEAR_MIRROR_DEG, SPECULAR_UNSEEN_WARNING,
};

/// The cluster tree's result, before any per-pixel refinement.
pub(crate) struct TreeStage {
    /// The light's intensity the fit uses.
    pub(crate) intensity: [f64; 3],
    source: IntensitySource,
    average: Vec<[f64; 3]>,
    covered: Vec<bool>,
    covered_px: Vec<u32>,
    k: usize,
    kmeans_sse: Vec<f64>,
    roots: Vec<u32>,
    leaves: Vec<tree::Leaf>,
    cluster: Vec<u32>,
    /// Every pixel's parameters: its cluster's (the refinement's start).
    pub(crate) params: Vec<BrdfParams>,
    unconverged: Vec<u32>,
    /// Pixels moved between clusters ([`crate::reassign`]).
    reassigned: usize,
    rmse_clusters: f64,
    timings: Vec<(String, f64)>,
}

/// The per-pixel stage's result.
pub(crate) struct Refined {
    /// Every pixel's parameters.
    pub(crate) params: Vec<BrdfParams>,
    /// Where asked for, the parameters before the per-pixel specular step: what the
    /// same settings give with `refine_specular` off.
    pub(crate) before_specular: Option<Vec<BrdfParams>>,
    lobes: Vec<Option<BrdfParams>>,
    refits: usize,
    pixel_lobes: usize,
    neighbour_lobes: usize,
    timings: Vec<(String, f64)>,
}

/// [`crate::fit`] with the settings as given.
pub(crate) fn fit_once(
    obs: &Observations,
    capture: &RegisteredCapture,
    cfg: &FitConfig,
    progress: &dyn Progress,
) -> Result<(FittedMaps, FitSummary), FitError> {
    let mut tree = fit_tree(obs, capture, cfg, progress)?;
    // Moved, not copied: the tree's parameters are not needed after the refinement.
    let start = std::mem::take(&mut tree.params);
    let refined = refine_stage(obs, &tree, start, cfg, progress, false);
    finish(obs, tree, refined, cfg, progress)
}

/// Light intensity, initial clusters and the recursive cluster fits.
pub(crate) fn fit_tree(
    obs: &Observations,
    capture: &RegisteredCapture,
    cfg: &FitConfig,
    progress: &dyn Progress,
) -> Result<TreeStage, FitError> {
    cfg.validate()?;
    let mut timings = Vec::new();
    let t = Instant::now();
    let (mut intensity, source) = light_intensity(obs, capture, cfg)?;
    let model = cfg.model.model();
    let npx = obs.pixels();
    progress.stage("initial clusters", 1);
    let Initial {
        average,
        covered,
        covered_px,
        init,
        members,
    } = initial_clusters(obs, cfg)?;
    if source == IntensitySource::Normalised {
        // The percentile rule reads a shiny dark material (brushed metal) as bright,
        // because highlight tails inflate its diffuse estimate; its specular albedo
        // would then hit the rho_d + rho_s <= 1 bound and the fit would clip every
        // highlight. Fit the initial clusters without that bound and raise the
        // intensity until the brightest one fits under it with a margin.
        let probe = Context {
            obs,
            model,
            intensity,
            cfg,
        };
        let peak = members
            .par_iter()
            .filter(|m| !m.is_empty())
            .map(|m| {
                let p = tree::initial_fit(&probe, m, false);
                (0..3).map(|c| p.rho_d[c] + p.rho_s[c]).fold(0.0, f64::max)
            })
            .reduce(|| 0.0, f64::max);
        if peak > ENERGY_MARGIN {
            intensity = intensity.map(|v| v * peak / ENERGY_MARGIN);
        }
    }
    let ctx = Context {
        obs,
        model,
        intensity,
        cfg,
    };
    progress.finish();
    timings.push(("initial clusters".to_string(), t.elapsed().as_secs_f64()));

    let t = Instant::now();
    progress.stage("cluster fits", init.k as u64);
    let (roots, mut leaves): (Vec<u32>, Vec<tree::Leaf>) = members
        .into_par_iter()
        .enumerate()
        .filter(|(_, m)| !m.is_empty())
        .flat_map_iter(|(k, m)| {
            let l = tree::fit_cluster(&ctx, m);
            progress.advance(1);
            l.into_iter().map(move |leaf| (k as u32, leaf))
        })
        .unzip();
    progress.finish();
    timings.push(("cluster fits".to_string(), t.elapsed().as_secs_f64()));

    let mut cluster = vec![u32::MAX; npx];
    let mut params = vec![BrdfParams::default(); npx];
    for (i, leaf) in leaves.iter().enumerate() {
        for &p in &leaf.pixels {
            cluster[p as usize] = i as u32;
        }
    }
    let t = Instant::now();
    let reassigned = if cfg.reassign_pixels {
        crate::reassign::reassign(&ctx, obs.grid.width, &mut leaves, &mut cluster)
    } else {
        0
    };
    timings.push(("pixels reassigned".to_string(), t.elapsed().as_secs_f64()));
    let unconverged: Vec<u32> = (0..leaves.len() as u32)
        .filter(|&i| !leaves[i as usize].converged)
        .collect();
    cluster::fill_unobserved(&obs.grid, &mut cluster, &covered);
    for (p, c) in params.iter_mut().zip(&cluster) {
        *p = leaves[*c as usize].params;
    }
    let sse_clusters: f64 = leaves.iter().map(|l| l.sse).sum();
    let n_obs_fit: usize = leaves.iter().map(|l| l.observations).sum();
    let rmse_clusters = (sse_clusters / (3 * n_obs_fit.max(1)) as f64).sqrt();

    Ok(TreeStage {
        intensity,
        source,
        average,
        covered,
        covered_px,
        k: init.k,
        kmeans_sse: init.sse,
        roots,
        leaves,
        cluster,
        params,
        unconverged,
        reassigned,
        rmse_clusters,
        timings,
    })
}

/// The room light of a capture ([`crate::room`]) as `cfg.room_light` asks: `auto`
/// estimates it where the flash frames come from a video (a sweep over distances tells
/// room light from albedo; a handful of photos from one distance band hardly does: real
/// cards-blue read 73-100% of the flash's light, unverifiable) and does not apply an
/// estimate at the top of the range searched (more likely material the flash model
/// misses than room light: simulated glossy facets read three times the true room
/// light). `obs` must hold no room light.
pub(crate) fn room_light(
    obs: &Observations,
    capture: &RegisteredCapture,
    cfg: &FitConfig,
) -> Result<Option<RoomLight>, FitError> {
    let swept = capture
        .sources
        .iter()
        .any(|s| s.stream == 0 && s.kind == svbrdf_core::capture::SourceKind::Video);
    let auto = match cfg.room_light {
        RoomLightMode::Off => return Ok(None),
        RoomLightMode::Auto if !swept => return Ok(None),
        mode => mode == RoomLightMode::Auto,
    };
    let mut room = estimate_room_light(obs, capture, cfg)?;
    if let Some(r) = room.as_mut().filter(|r| auto && r.at_bound()) {
        r.applied = false;
    }
    Ok(room)
}

/// The estimate itself: the initial clusters, each fitted with an isotropic lobe and a
/// flat normal under no room light, give the lobe shapes; the full model is used even
/// for a diffuse-only fit, so that both read the room alike.
fn estimate_room_light(
    obs: &Observations,
    capture: &RegisteredCapture,
    cfg: &FitConfig,
) -> Result<Option<RoomLight>, FitError> {
    let (intensity, _) = light_intensity(obs, capture, cfg)?;
    let probe_cfg = FitConfig {
        diffuse_only: false,
        ..cfg.clone()
    };
    let model = cfg.model.model();
    let probe = Context {
        obs,
        model,
        intensity,
        cfg: &probe_cfg,
    };
    let Initial { members, .. } = initial_clusters(obs, cfg)?;
    let clusters: Vec<(Vec<u32>, BrdfParams)> = members
        .into_par_iter()
        .filter(|m| !m.is_empty())
        .map(|m| {
            let p = tree::initial_fit(&probe, &m, false);
            (m, p)
        })
        .collect();
    Ok(crate::room::estimate(obs, &clusters, model, intensity))
}

/// The paper's initial clusters (k-means on the pixels' mean colours, 3.2.1).
pub(crate) struct Initial {
    /// Mean colour per pixel.
    pub(crate) average: Vec<[f64; 3]>,
    /// Pixels with enough observations to fit.
    pub(crate) covered: Vec<bool>,
    /// Their indices.
    pub(crate) covered_px: Vec<u32>,
    /// The k-means result.
    pub(crate) init: cluster::InitialClusters,
    /// Pixels per initial cluster.
    pub(crate) members: Vec<Vec<u32>>,
}

/// [`Initial`] clusters of the pixels observed at least `min_observations` times; an
/// error when too few are.
pub(crate) fn initial_clusters(obs: &Observations, cfg: &FitConfig) -> Result<Initial, FitError> {
    let npx = obs.pixels();
    let average = obs.mean_colors();
    let covered: Vec<bool> = (0..npx)
        .map(|p| obs.count(p) >= cfg.min_observations)
        .collect();
    let covered_px: Vec<u32> = (0..npx as u32).filter(|&p| covered[p as usize]).collect();
    if covered_px.len() < cfg.min_cluster_px {
        return Err(FitError::NoData(format!(
            "only {} of {} output pixels have at least {} observations (need {}): \
             the frames do not cover the region",
            covered_px.len(),
            npx,
            cfg.min_observations,
            cfg.min_cluster_px
        )));
    }
    let albedo;
    let grouped = match cfg.cluster_colour {
        ClusterColour::Mean => &average,
        ClusterColour::Albedo => {
            albedo = obs.albedo_colors();
            &albedo
        }
    };
    let colors: Vec<[f64; 3]> = covered_px.iter().map(|&p| grouped[p as usize]).collect();
    let init =
        cluster::initial_clusters(&colors, cfg.k_min, cfg.k_max, cfg.kmeans_sample, cfg.seed);
    let mut members: Vec<Vec<u32>> = vec![Vec::new(); init.k];
    for (&p, &l) in covered_px.iter().zip(&init.labels) {
        members[l as usize].push(p);
    }
    Ok(Initial {
        average,
        covered,
        covered_px,
        init,
        members,
    })
}

/// Per-pixel refinement of diffuse albedo and normal between lobe refits, then (with
/// `refine_specular`) per-pixel lobes where the highlight's peak was seen. Reads only
/// the refinement's settings of `cfg` (the tree's are `tree`'s).
pub(crate) fn refine_stage(
    obs: &Observations,
    tree: &TreeStage,
    start: Vec<BrdfParams>,
    cfg: &FitConfig,
    progress: &dyn Progress,
    keep_before_specular: bool,
) -> Refined {
    let model = cfg.model.model();
    let npx = obs.pixels();
    let ctx = Context {
        obs,
        model,
        intensity: tree.intensity,
        cfg,
    };
    let (covered, cluster, leaves) = (&tree.covered[..], &tree.cluster[..], &tree.leaves[..]);
    let mut params = start;
    let mut timings = Vec::new();
    let mut before_specular = None;
    let t = Instant::now();
    let mut refits = 0;
    let mut pixel_lobes = 0;
    let mut neighbour_lobes = 0;
    let mut lobes: Vec<Option<BrdfParams>> = vec![None; leaves.len()];
    if cfg.refine {
        progress.stage("per-pixel refinement", 1);
        // Where the light came from too narrow a range of directions to measure the
        // normal, the refinement may move it less (none at all lit from one direction).
        let trust = normal_trust(obs, covered, cfg);
        let anchor = |px: usize| {
            let l = &leaves[cluster[px] as usize].params;
            let t = trust.as_ref().map_or(1.0, |t| t[px]);
            ([l.normal_theta_x, l.normal_theta_y], t)
        };
        refits = if model.kind() == ModelKind::Ward && !cfg.diffuse_only {
            cfg.lobe_refits
        } else {
            0
        };
        // The iterations are spread over the passes between lobe refits: each pass
        // starts from a sharper lobe, which is worth more than further iterations
        // against the first one.
        let iterations = cfg.refine_iterations.div_ceil(refits.max(1));
        let diffuse = Freedom::DIFFUSE_AND_NORMAL;
        refine(&ctx, &mut params, covered, anchor, iterations, diffuse);
        progress.finish();
        timings.push((
            "per-pixel refinement".to_string(),
            t.elapsed().as_secs_f64(),
        ));
        // Clusters whose lobe the last refit moved: only their pixels are refined again.
        let mut moved = vec![true; leaves.len()];
        for pass in 0..refits {
            let t = Instant::now();
            if pass > 0 {
                progress.stage("per-pixel refinement", 1);
                let last = pass + 1 == refits;
                let again: Vec<bool> = covered
                    .iter()
                    .zip(cluster)
                    .map(|(&c, &l)| c && (last || !cfg.refine_moved_only || moved[l as usize]))
                    .collect();
                refine(&ctx, &mut params, &again, anchor, iterations, diffuse);
                progress.finish();
                timings.push((
                    "per-pixel refinement".to_string(),
                    t.elapsed().as_secs_f64(),
                ));
            }
            let t = Instant::now();
            progress.stage("lobe refit", 1);
            let new: Vec<Option<BrdfParams>> = leaves
                .par_iter()
                .map(|l| tree::refit_lobe(&ctx, l, &params))
                .collect();
            for (i, q) in new.into_iter().enumerate() {
                let before = lobes[i].unwrap_or(leaves[i].params);
                moved[i] = q.is_some_and(|q| tree::lobe_moved(&before, &q));
                if q.is_some() {
                    lobes[i] = q;
                }
            }
            for (p, &c) in params.iter_mut().zip(cluster) {
                if let Some(q) = lobes[c as usize] {
                    refine::put_lobe(p, q.rho_s, q.alpha_x, q.alpha_y);
                }
            }
            progress.finish();
            timings.push(("lobe refit".to_string(), t.elapsed().as_secs_f64()));
        }
        if keep_before_specular {
            before_specular = Some(params.clone());
        }
        if cfg.refine_specular && !cfg.diffuse_only {
            // Where the pixel's own observations measure its lobe (peak seen
            // unclipped, or its flank), the pixel's own lobe: specular albedo and
            // roughness too, pulled towards its cluster's.
            let t = Instant::now();
            progress.stage("per-pixel specular", 1);
            let mut measured: Vec<bool> = (0..npx)
                .into_par_iter()
                .map(|p| covered[p] && confidence::lobe_measured(obs, p, &params[p]))
                .collect();
            pixel_lobes = measured.iter().filter(|&&b| b).count();
            // In anisotropic clusters, pixels seen often enough take their lobe from
            // their neighbours instead.
            let cluster_lobes: Vec<BrdfParams> = (0..leaves.len())
                .map(|c| lobes[c].unwrap_or(leaves[c].params))
                .collect();
            let from_neighbours = neighbour::chosen(obs, &measured, cluster, &cluster_lobes, cfg);
            for (m, &n) in measured.iter_mut().zip(&from_neighbours) {
                *m &= !n;
            }
            refine(
                &ctx,
                &mut params,
                &measured,
                anchor,
                cfg.refine_iterations,
                Freedom::FULL,
            );
            if !from_neighbours.is_empty() {
                neighbour_lobes = neighbour::neighbour_lobes(
                    &ctx,
                    &mut params,
                    &from_neighbours,
                    cluster,
                    anchor,
                );
            }
            progress.finish();
            timings.push(("per-pixel specular".to_string(), t.elapsed().as_secs_f64()));
        }
    }

    Refined {
        params,
        before_specular,
        lobes,
        refits,
        pixel_lobes,
        neighbour_lobes,
        timings,
    }
}

/// Per pixel, the share of `refine_max_normal_change_deg` the refinement may move its
/// normal: its normal confidence over `normal_trust_full_confidence`, times the square
/// root of its frames over `normal_trust_full_views`, at most 1; `None` (the whole
/// change everywhere) when the setting is off.
pub(crate) fn normal_trust(
    obs: &Observations,
    covered: &[bool],
    cfg: &FitConfig,
) -> Option<Vec<f64>> {
    let full = cfg.normal_trust_full_confidence;
    if full <= 0.0 {
        return None;
    }
    let trust = (0..covered.len())
        .into_par_iter()
        .map(|p| {
            if !covered[p] {
                return 1.0;
            }
            let views = match cfg.normal_trust_full_views {
                0 => 1.0,
                v => (obs.count(p) as f64 / v as f64).sqrt(),
            };
            (f64::from(confidence::normal_confidence(obs, p)) / full * views).min(1.0)
        })
        .collect();
    Some(trust)
}

/// Re-rendering check, confidence, warnings and the records.
pub(crate) fn finish(
    obs: &Observations,
    tree: TreeStage,
    refined: Refined,
    cfg: &FitConfig,
    progress: &dyn Progress,
) -> Result<(FittedMaps, FitSummary), FitError> {
    let model = cfg.model.model();
    let npx = obs.pixels();
    let TreeStage {
        intensity,
        source,
        average,
        covered,
        covered_px,
        k: tree_k,
        kmeans_sse: tree_sse,
        roots,
        leaves,
        cluster,
        unconverged,
        reassigned,
        rmse_clusters,
        mut timings,
        ..
    } = tree;
    let Refined {
        params,
        lobes,
        refits,
        pixel_lobes,
        neighbour_lobes,
        timings: refine_timings,
        ..
    } = refined;
    timings.extend(refine_timings);
    let t = Instant::now();
    progress.stage("re-rendering check", 1);
    let (residual, frames) = render::rerender_check(obs, &params, model, intensity);
    progress.finish();
    timings.push(("re-rendering check".to_string(), t.elapsed().as_secs_f64()));
    let (sse, n): (f64, usize) = frames
        .iter()
        .map(|f| {
            (
                f.rmse * f.rmse * (3 * f.observations) as f64,
                f.observations,
            )
        })
        .fold((0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    let rmse_final = (sse / (3 * n.max(1)) as f64).sqrt();

    let coverage = (0..npx).map(|p| obs.count(p) as u32).collect();
    let t = Instant::now();
    let (confidence, confidence_summary) = confidence::confidence(obs, &params);
    timings.push(("confidence".to_string(), t.elapsed().as_secs_f64()));
    let cluster_specular = confidence::cluster_specular(obs, &confidence, &cluster, leaves.len());
    let mut warnings = Vec::new();
    if confidence_summary.specular_unseen > SPECULAR_UNSEEN_WARNING {
        warnings.push(format!(
            "the highlight was never seen on {:.0}% of the surface: their gloss is copied from similar regions, not measured (see maps/confidence.png, green channel); sweep the phone over those parts too",
            100.0 * confidence_summary.specular_unseen
        ));
    }
    let unseen = npx - covered_px.len();
    if unseen * 20 > npx {
        warnings.push(format!(
            "{:.0}% of the output pixels ({unseen} of {npx}) were seen by fewer than {} frames: their parameters are copied from the nearest fitted cluster, not measured (see maps/coverage.png)",
            100.0 * unseen as f64 / npx as f64,
            cfg.min_observations
        ));
    }
    // Clipped observations are among `obs` when kept as censored values, else dropped.
    let all_obs = obs.len() as u64 + if cfg.censor_clipped { 0 } else { obs.clipped };
    if all_obs > 0 && obs.clipped * 4 > all_obs {
        warnings.push(format!(
            "{:.0}% of the observations have a clipped channel: the video is overexposed, so highlights are measured only in part (lower the exposure)",
            100.0 * obs.clipped as f64 / all_obs as f64
        ));
    }
    let clipped_near_mirror = if cfg.censor_clipped {
        obs.clipped_near_mirror(NEAR_MIRROR_DEG)
    } else {
        None
    };
    if let Some(c) = clipped_near_mirror.filter(|c| *c > CLIPPED_PEAK_WARNING) {
        warnings.push(format!(
            "{:.0}% of the observations within {NEAR_MIRROR_DEG} degrees of the mirror direction have a clipped channel: the peaks of the glossiest highlights are lower bounds, so those parts may render dimmer than they are under a light near their mirror direction (record 10-bit HDR, e.g. HLG, or lower the exposure; docs/CAPTURE.md)",
            100.0 * c
        ));
    }
    let summary = FitSummary {
        warnings,
        model: model.name().to_string(),
        light_intensity: intensity,
        light_intensity_source: source,
        observations: obs.len(),
        clipped_observations: obs.clipped,
        clipped_near_mirror,
        covered_pixels: covered_px.len(),
        pixels: npx,
        initial_clusters: tree_k,
        kmeans_sse: tree_sse,
        final_clusters: leaves.len(),
        max_depth: leaves.iter().map(|l| l.depth).max().unwrap_or(0),
        unconverged_clusters: unconverged,
        reassigned_pixels: reassigned,
        refined: cfg.refine,
        lobe_refits: refits,
        refitted_clusters: lobes.iter().filter(|l| l.is_some()).count(),
        pixel_lobes,
        neighbour_lobes,
        rmse_clusters,
        rmse_final,
        frames,
        timings,
        confidence: Some(confidence_summary),
        clusters_without_peak: cluster_specular
            .iter()
            .filter(|c| c.is_some_and(|c| c[0] == 0.0))
            .count(),
        lobes_from_parent: leaves.iter().filter(|l| l.lobe_from_parent).count(),
        turned_grain: summary::turned_grain(&params, &covered),
        selection: None,
        room_light: None,
    };
    Ok((
        FittedMaps {
            grid: obs.grid,
            params,
            cluster,
            coverage,
            average,
            residual,
            confidence,
            clusters: leaves
                .iter()
                .enumerate()
                .map(|(i, l)| ClusterInfo {
                    id: i as u32,
                    initial: roots[i],
                    pixels: l.pixels.len(),
                    depth: l.depth,
                    params: l.params,
                    refitted_lobe: lobes[i],
                    rmse: (l.sse / (3 * l.observations.max(1)) as f64).sqrt(),
                    converged: l.converged,
                    specular_seen: cluster_specular[i],
                    lobe_from_parent: l.lobe_from_parent,
                })
                .collect(),
        },
        summary,
    ))
}
