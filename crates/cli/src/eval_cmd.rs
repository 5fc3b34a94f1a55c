//! `svbrdf import` (registered image sets from other tools) and `svbrdf eval`
//! (held-out evaluation).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::Args;
use serde_json::json;
use svbrdf_fit::holdout::{
    evaluate_holdout, HoldoutConfig, HoldoutReport, ImageMetric, MeanErrors,
};

use crate::flip::{FlipTool, FLIP_INSTALL};

use crate::fit_cmd::{CvFrames, FitOptions};

#[derive(Args, Clone)]
pub struct ImportArgs {
    /// A folder in the MaterialGAN / svbrdf-diff-renderer layout: 00.png, 01.png, ...
    /// (sRGB photos already rectified to the plane), camera_pos.txt and light_pos.txt
    /// (x,y,z in cm per photo, origin at the image centre, z along the normal),
    /// image_size.txt (image width in cm), optional light_power.txt.
    #[arg(long)]
    pub materialgan: PathBuf,
    /// Output folder for the registered capture (capture.json; the photos stay where
    /// they are and are referenced by absolute path).
    #[arg(long)]
    pub out: PathBuf,
    /// Use light_power.txt as the flash intensity (MaterialGAN's uncalibrated scale);
    /// by default the intensity is unknown and the fit normalises albedos.
    #[arg(long)]
    pub use_light_power: bool,
    /// Replace the output folder if it exists.
    #[arg(long)]
    pub overwrite: bool,
}

pub fn run_import(a: &ImportArgs) -> Result<PathBuf> {
    let cap = svbrdf_core::import::import_materialgan(
        &a.materialgan,
        &svbrdf_core::import::ImportOptions {
            use_light_power: a.use_light_power,
        },
    )?;
    let staging = svbrdf_core::fsutil::StagingDir::new(
        &a.out,
        a.overwrite,
        std::slice::from_ref(&a.materialgan),
    )?;
    cap.save(staging.path())?;
    let out = staging.commit()?;
    say!(
        "wrote {} ({} photos, {}x{} px over {:.3} x {:.3} cm, {:.1} px/cm; light intensity {})",
        out.join(svbrdf_core::capture::CAPTURE_FILE).display(),
        cap.frames.len(),
        cap.frames[0].width,
        cap.frames[0].height,
        cap.region.width(),
        cap.region.height(),
        cap.px_per_cm,
        match cap.light_intensity {
            Some(i) => format!("{:?} from light_power.txt", i),
            None => "unknown (normalised by the fit)".into(),
        }
    );
    Ok(out)
}

#[derive(Args, Clone)]
#[command(allow_negative_numbers = true)]
pub struct EvalArgs {
    /// Registered capture (a folder holding capture.json).
    #[arg(long)]
    pub capture: PathBuf,
    /// Frame ids to hold out, comma separated (e.g. 3,7).
    #[arg(long, value_delimiter = ',', required_unless_present = "leave_out")]
    pub holdout: Option<Vec<u32>>,
    /// Instead of --holdout: every combination of this many frames in turn (36 fits
    /// for 2 of 9 photos); per-combination results in OUT/holdout-<ids>/.
    #[arg(long, conflicts_with = "holdout")]
    pub leave_out: Option<usize>,
    /// Output folder: maps/ (the fit), eval/ (eval.json and photo | rendering |
    /// difference strips) and report.html.
    #[arg(long)]
    pub out: PathBuf,
    /// Fit a Lambertian material only (rho_s = 0): the baseline that shows what the
    /// specular fit adds.
    #[arg(long)]
    pub diffuse_only: bool,
    /// Also evaluate the diffuse-only baseline (into OUT/diffuse-only/) and report both.
    #[arg(long, conflicts_with = "diffuse_only")]
    pub baseline: bool,
    /// NVIDIA's FLIP evaluator (`flip`, pip flip-evaluator) for the perceptual figure;
    /// default: $SVBRDF_FLIP, else `flip` on the PATH, else FLIP is not reported.
    #[arg(long)]
    pub flip: Option<PathBuf>,
    /// How to fit (as `svbrdf fit`; a lower --px-per-cm is faster).
    #[command(flatten)]
    pub fit: FitOptions,
    /// Replace the output folder if it exists.
    #[arg(long)]
    pub overwrite: bool,
}

fn holdout_config(a: &EvalArgs, holdout: Vec<u32>, diffuse_only: bool) -> Result<HoldoutConfig> {
    let mut fit = crate::fit_cmd::fit_config(&a.fit)?;
    fit.diffuse_only = diffuse_only;
    Ok(HoldoutConfig {
        holdout,
        fit,
        strip_px: 384,
    })
}

fn one(
    a: &EvalArgs,
    holdout: Vec<u32>,
    out: &Path,
    diffuse_only: bool,
    flip: Option<&FlipTool>,
) -> Result<HoldoutReport> {
    let cfg = holdout_config(a, holdout, diffuse_only)?;
    let progress = crate::progress::Bars::new();
    let metric = flip.map(|f| f as &dyn ImageMetric);
    let (report, out, fitted) = evaluate_holdout(
        &a.capture,
        out,
        a.overwrite,
        &cfg,
        &CvFrames,
        metric,
        &progress,
    )
    .with_context(|| format!("evaluating {}", a.capture.display()))?;
    let maps = svbrdf_export::MaterialMaps {
        model: cfg.fit.model,
        grid: fitted.grid,
        params: fitted.params,
        coverage: fitted.coverage,
        confidence: fitted.confidence,
    };
    svbrdf_export::report::write_report(&out, Some(&maps))?;
    say!(
        "{}held out {:?}: linear RMSE {:.4} ({:.1}% of the mean), sRGB RMSE {:.4}, SSIM linear {:.3}, sRGB {:.3}{}; {}",
        if diffuse_only { "diffuse only: " } else { "" },
        report.holdout,
        report.mean.rmse_linear,
        100.0 * report.mean.relative_rmse_linear,
        report.mean.rmse_srgb,
        report.mean.ssim_linear,
        report.mean.ssim_srgb,
        flip_text(&report.mean),
        out.join("report.html").display()
    );
    Ok(report)
}

/// ", FLIP 0.123" where the figure exists.
fn flip_text(m: &MeanErrors) -> String {
    m.flip.map(|f| format!(", FLIP {f:.3}")).unwrap_or_default()
}

/// Per held-out set, whether the full fit beats the diffuse-only baseline in each
/// figure (sRGB RMSE and FLIP lower, SSIM higher), and how many sets it wins.
fn pairwise(full: &[HoldoutReport], base: &[HoldoutReport]) -> serde_json::Value {
    let mut rows = Vec::new();
    let (mut rmse, mut ssim, mut flip, mut all) = (0, 0, 0, 0);
    let mut with_flip = 0;
    for (f, b) in full.iter().zip(base) {
        let w_rmse = f.mean.rmse_srgb < b.mean.rmse_srgb;
        let w_ssim = f.mean.ssim_srgb > b.mean.ssim_srgb;
        let w_flip = match (f.mean.flip, b.mean.flip) {
            (Some(x), Some(y)) => Some(x < y),
            _ => None,
        };
        rmse += usize::from(w_rmse);
        ssim += usize::from(w_ssim);
        flip += usize::from(w_flip == Some(true));
        with_flip += usize::from(w_flip.is_some());
        all += usize::from(w_rmse && w_ssim && w_flip != Some(false));
        rows.push(json!({
            "holdout": f.holdout,
            "full": f.mean,
            "diffuse_only": b.mean,
            "full_wins": {"rmse_srgb": w_rmse, "ssim_srgb": w_ssim, "flip": w_flip},
        }));
    }
    json!({
        "sets": rows.len(),
        "full_wins": {
            "rmse_srgb": rmse,
            "ssim_srgb": ssim,
            "flip": (with_flip > 0).then_some(flip),
            "every_figure": all,
        },
        "per_set": rows,
    })
}

/// Every `k`-subset of `ids`, in lexicographic order.
fn combinations(ids: &[u32], k: usize) -> Vec<Vec<u32>> {
    let mut out = Vec::new();
    let mut idx: Vec<usize> = (0..k).collect();
    if k == 0 || k > ids.len() {
        return out;
    }
    loop {
        out.push(idx.iter().map(|&i| ids[i]).collect());
        let mut i = k;
        while i > 0 && idx[i - 1] == ids.len() - k + i - 1 {
            i -= 1;
        }
        if i == 0 {
            return out;
        }
        idx[i - 1] += 1;
        for j in i..k {
            idx[j] = idx[j - 1] + 1;
        }
    }
}

/// `svbrdf eval`: one JSON object per evaluation on stdout's last line is not needed
/// here; `eval.json` files hold the figures and the summary is printed.
pub fn run_eval(a: &EvalArgs) -> Result<serde_json::Value> {
    svbrdf_cv::set_single_threaded()?;
    crate::alloc::retain_freed_pages(false);
    let variants: Vec<bool> = if a.baseline {
        vec![false, true]
    } else {
        vec![a.diffuse_only]
    };
    let sets: Vec<Vec<u32>> = match (&a.holdout, a.leave_out) {
        (Some(h), _) => vec![h.clone()],
        (None, Some(k)) => {
            let cap = svbrdf_core::capture::RegisteredCapture::load(&a.capture)?;
            let ids: Vec<u32> = cap.frames.iter().map(|f| f.id).collect();
            anyhow::ensure!(
                k >= 1 && k < ids.len(),
                "invalid --leave-out {k} (expected 1 to {}, fewer than the capture's {} frames)",
                ids.len().saturating_sub(1),
                ids.len()
            );
            combinations(&ids, k)
        }
        (None, None) => anyhow::bail!("give --holdout IDS or --leave-out K"),
    };
    let flip = FlipTool::locate(a.flip.as_deref())?;
    if flip.is_none() {
        say!("FLIP not reported: no `flip` command found ({FLIP_INSTALL})");
    }
    let mut summary = json!({
        "capture": a.capture.display().to_string(),
        "sets": sets.len(),
        "flip_metric": flip.as_ref().map(|f| f.describe()),
    });
    let mut by_variant = Vec::new();
    for diffuse_only in variants {
        let base = if diffuse_only && a.baseline {
            a.out.join("diffuse-only")
        } else {
            a.out.clone()
        };
        let mut reports = Vec::new();
        for set in &sets {
            let dir = if sets.len() == 1 {
                base.clone()
            } else {
                let name: Vec<String> = set.iter().map(|i| format!("{i:02}")).collect();
                base.join(format!("holdout-{}", name.join("-")))
            };
            // A finished set of an interrupted leave-k-out run is reused.
            let done = dir
                .join(svbrdf_fit::holdout::EVAL_DIR)
                .join(svbrdf_fit::holdout::EVAL_FILE);
            if sets.len() > 1 && !a.overwrite && done.is_file() {
                say!("reusing {}", done.display());
                reports.push(svbrdf_core::fsutil::read_json(&done)?);
                continue;
            }
            reports.push(one(a, set.clone(), &dir, diffuse_only, flip.as_ref())?);
        }
        let all: Vec<&svbrdf_fit::holdout::HoldoutError> =
            reports.iter().flat_map(|r| r.images.iter()).collect();
        let mean = MeanErrors::of(all.iter().copied());
        let key = if diffuse_only { "diffuse_only" } else { "full" };
        summary[key] = json!({
            "mean": mean,
            "fit_seconds_mean": reports.iter().map(|r| r.fit_seconds).sum::<f64>() / reports.len().max(1) as f64,
            "per_set": reports.iter().map(|r| json!({"holdout": r.holdout, "mean": r.mean})).collect::<Vec<_>>(),
        });
        if sets.len() > 1 {
            say!(
                "{}leave-{}-out over {} sets: linear RMSE {:.4} ({:.1}%), sRGB RMSE {:.4}, SSIM linear {:.3}, sRGB {:.3}{}",
                if diffuse_only { "diffuse only: " } else { "" },
                sets[0].len(),
                sets.len(),
                mean.rmse_linear,
                100.0 * mean.relative_rmse_linear,
                mean.rmse_srgb,
                mean.ssim_linear,
                mean.ssim_srgb,
                flip_text(&mean)
            );
        }
        by_variant.push(reports);
    }
    if let [full, base] = &by_variant[..] {
        let p = pairwise(full, base);
        let w = &p["full_wins"];
        say!(
            "full fit against diffuse-only, per held-out set: lower sRGB RMSE in {} of {}, higher SSIM in {}, lower FLIP in {}; all of them in {}",
            w["rmse_srgb"],
            p["sets"],
            w["ssim_srgb"],
            if w["flip"].is_null() { "- (no FLIP)".to_string() } else { w["flip"].to_string() },
            w["every_figure"]
        );
        summary["pairwise"] = p;
    }
    if sets.len() > 1 || a.baseline {
        svbrdf_core::fsutil::write_json(&a.out.join("eval-summary.json"), &summary)?;
    }
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::combinations;

    #[test]
    fn combinations_are_complete_and_ordered() {
        let c = combinations(&[0, 1, 2, 3], 2);
        assert_eq!(
            c,
            vec![
                vec![0, 1],
                vec![0, 2],
                vec![0, 3],
                vec![1, 2],
                vec![1, 3],
                vec![2, 3]
            ]
        );
        assert_eq!(combinations(&(0..9).collect::<Vec<_>>(), 2).len(), 36);
        assert!(combinations(&[1, 2], 3).is_empty());
    }
}
