//! What a fit returns: the maps on the output grid, the final clusters and the figures
//! of the run (`fit.json`).

use serde::{Deserialize, Serialize};
use svbrdf_core::brdf::BrdfParams;
use svbrdf_core::plane::PlaneGrid;

use crate::{confidence, render, select};
#[cfg(doc)]
use crate::{tree, FitConfig, NEAR_MIRROR_DEG};

/// Fitted maps on the output grid.
#[derive(Debug, Clone)]
pub struct FittedMaps {
    /// The grid.
    pub grid: PlaneGrid,
    /// BRDF per pixel (row-major).
    pub params: Vec<BrdfParams>,
    /// Final cluster per pixel.
    pub cluster: Vec<u32>,
    /// Observations per pixel (0: filled from the nearest observed pixel's cluster).
    pub coverage: Vec<u32>,
    /// Mean observed linear colour per pixel.
    pub average: Vec<[f64; 3]>,
    /// RMS re-rendering error per pixel (linear radiance).
    pub residual: Vec<f32>,
    /// Confidence per pixel in [0, 1]: diffuse, specular lobe, normal (see
    /// [`confidence`]).
    pub confidence: Vec<[f32; 3]>,
    /// The final clusters, indexed by the ids in `cluster`.
    pub clusters: Vec<ClusterInfo>,
}

/// One final cluster as written to `clusters.json`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ClusterInfo {
    /// Id (value in the cluster map).
    pub id: u32,
    /// Pixels (observed ones; filled pixels are not counted).
    pub pixels: usize,
    /// Split level (0: an initial k-means cluster).
    pub depth: usize,
    /// The initial (k-means) cluster it was split from.
    #[serde(default)]
    pub initial: u32,
    /// The cluster's BRDF (before per-pixel refinement).
    pub params: BrdfParams,
    /// The specular lobe of the last accepted lobe refit (`rho_s`, `alpha_x`,
    /// `alpha_y`; its `rho_d` and normal are zero: those are per pixel in the maps),
    /// which the maps use; absent where no refit ran or none was accepted (see
    /// [`tree::refit_lobe`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub refitted_lobe: Option<BrdfParams>,
    /// RMS error over its pixels' observations (at most `max_split_observations` per
    /// pixel), linear radiance.
    pub rmse: f64,
    /// Whether its solver converged before the iteration cap.
    pub converged: bool,
    /// Shares of its pixels whose highlight peak was seen unclipped, only its flank or
    /// clipped, or never (see [`confidence`]): a cluster none of whose pixels saw the
    /// peak has a lobe fitted on flanks alone.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub specular_seen: Option<[f64; 3]>,
    /// Whether it kept its parent's lobe (`params` holds it) because no frame saw the
    /// lobe fitted from its own observations (see [`tree`]'s `hold_unseen_lobe`);
    /// written only when true.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub lobe_from_parent: bool,
}

/// How the light intensity was obtained.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum IntensitySource {
    /// Given on the command line or in the configuration.
    Config,
    /// From the registered capture (the simulator knows it).
    Capture,
    /// Normalised so that the bright end of the material has albedo
    /// [`FitConfig::normalised_albedo`]: albedos are relative.
    Normalised,
}

/// Figures of one fit.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FitSummary {
    /// Model name.
    pub model: String,
    /// Light intensity used per channel.
    pub light_intensity: [f64; 3],
    /// Where it came from.
    pub light_intensity_source: IntensitySource,
    /// Observations used.
    pub observations: usize,
    /// Observations with a clipped channel (dropped, or kept as censored values with
    /// `censor_clipped`).
    pub clipped_observations: u64,
    /// Share of the observations within [`NEAR_MIRROR_DEG`] of the mirror direction
    /// (half vector against the plane's normal) that have a clipped channel: how
    /// much of the highlights' peaks the video's range lost (`None` when clipped
    /// observations were dropped, or none lie that close).
    #[serde(default)]
    pub clipped_near_mirror: Option<f64>,
    /// Pixels with at least `min_observations`.
    pub covered_pixels: usize,
    /// All pixels.
    pub pixels: usize,
    /// Doubts about the input or the result, one sentence each (also on stderr, in
    /// run.json and in the report).
    #[serde(default)]
    pub warnings: Vec<String>,
    /// Chosen k of the initial clustering.
    pub initial_clusters: usize,
    /// Summed squared k-means error per k from `k_min`.
    pub kmeans_sse: Vec<f64>,
    /// Final clusters.
    pub final_clusters: usize,
    /// Deepest split level reached.
    pub max_depth: usize,
    /// Final clusters whose solver stopped at the iteration cap (reported, not fatal).
    pub unconverged_clusters: Vec<u32>,
    /// Pixels moved to a neighbouring cluster whose BRDF explains them far better
    /// (`reassign_pixels`; over both passes).
    #[serde(default)]
    pub reassigned_pixels: usize,
    /// Whether the per-pixel refinement ran.
    pub refined: bool,
    /// Lobe refits run after the refinement (each after a refinement pass).
    #[serde(default)]
    pub lobe_refits: usize,
    /// Clusters whose maps use a refitted lobe.
    #[serde(default)]
    pub refitted_clusters: usize,
    /// Pixels with a lobe of their own (`refine_specular`: where their observations
    /// measure it, at the peak unclipped or on the flank); the others carry their
    /// cluster's.
    #[serde(default)]
    pub pixel_lobes: usize,
    /// Of those, pixels whose lobe came from their neighbours
    /// (`neighbour_lobes_min_anisotropy`).
    #[serde(default)]
    pub neighbour_lobes: usize,
    /// RMS error of the cluster solutions (before refinement, linear), over the
    /// observations the split decisions use: at most `max_split_observations` per pixel.
    pub rmse_clusters: f64,
    /// RMS re-rendering error of the final maps over every observation.
    pub rmse_final: f64,
    /// Re-rendering error per input frame.
    pub frames: Vec<render::FrameError>,
    /// What the confidence maps say (see [`confidence`]); absent in fits written
    /// before they existed.
    #[serde(default)]
    pub confidence: Option<confidence::ConfidenceSummary>,
    /// Final clusters none of whose pixels saw the highlight's peak unclipped: their
    /// lobe rests on flanks, clipped peaks or nothing.
    #[serde(default)]
    pub clusters_without_peak: usize,
    /// Final clusters that kept their parent's lobe because no frame saw the lobe
    /// their own observations gave (clusters.json: `lobe_from_parent`).
    #[serde(default)]
    pub lobes_from_parent: usize,
    /// Anisotropic pixels whose lobe the fit turned away from the plane's axes
    /// ([`crate::FitConfig::tangent_rotation_depth`]); absent when none.
    #[serde(default)]
    pub turned_grain: Option<TurnedGrain>,
    /// How the settings were chosen on held-out frames (absent when not validated).
    #[serde(default)]
    pub selection: Option<select::Selection>,
    /// The room light found and fitted with every observation (absent when
    /// `room_light` is off or no pixel had enough unclipped observations).
    #[serde(default)]
    pub room_light: Option<crate::room::RoomLight>,
    /// Seconds per step.
    pub timings: Vec<(String, f64)>,
}

/// Where the fitted anisotropy does not lie along the plane's axes.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TurnedGrain {
    /// Share of the covered pixels that are anisotropic (one roughness over 1.2 times
    /// the other) with their tangent turned more than [`TURNED_DEG`] from either axis.
    pub share: f64,
    /// Median turn of those pixels, degrees in (0, 90): the tangent (`alpha_x`) from
    /// plane +x towards +y.
    pub median_deg: f64,
}

/// A tangent turned by less than this from either of the plane's axes (degrees) counts
/// as along it.
pub const TURNED_DEG: f64 = 2.0;

/// [`TurnedGrain`] of fitted parameters over the covered pixels; `None` when no pixel
/// is turned.
pub fn turned_grain(params: &[BrdfParams], covered: &[bool]) -> Option<TurnedGrain> {
    let mut n = 0usize;
    let mut turned = Vec::new();
    for (p, _) in params.iter().zip(covered).filter(|(_, c)| **c) {
        n += 1;
        let (lo, hi) = (p.alpha_x.min(p.alpha_y), p.alpha_x.max(p.alpha_y));
        let deg = p.canonical_rotation().tangent_rotation.to_degrees();
        if hi > 1.2 * lo && deg > TURNED_DEG && deg < 90.0 - TURNED_DEG {
            turned.push(deg);
        }
    }
    if turned.is_empty() {
        return None;
    }
    let mid = turned.len() / 2;
    let median_deg = *turned.select_nth_unstable_by(mid, f64::total_cmp).1;
    Some(TurnedGrain {
        share: turned.len() as f64 / n.max(1) as f64,
        median_deg,
    })
}
