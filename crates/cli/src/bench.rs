//! `svbrdf bench`: hot-path throughput as JSON lines (one object per measurement), so
//! figures can be compared across commits on the same machine.

use std::time::Instant;

use anyhow::Result;
use clap::Args;
use rayon::prelude::*;
use serde_json::json;
use svbrdf_core::brdf::{BrdfParams, LightView, ModelKind, Prepared};
use svbrdf_core::geometry::Vec3;

pub use crate::accuracy::{align_accuracy, fit_accuracy, load_truth, maps_accuracy, truth_section};

#[derive(Args)]
pub struct BenchArgs {
    /// Compare an alignment (a registered capture folder) with the ground truth of the
    /// simulated capture given by --truth, and print the accuracy as JSON.
    #[arg(long, requires = "truth")]
    align_capture: Option<std::path::PathBuf>,
    /// A folder written by `svbrdf synth` (its ground_truth/truth.json is used).
    #[arg(long)]
    truth: Option<std::path::PathBuf>,
    /// With --align-capture: a second alignment of the same video made with
    /// `--all-pairs`; reports how many of its coarse connections the default search found.
    #[arg(long, requires = "align_capture")]
    all_pairs_capture: Option<std::path::PathBuf>,
    /// Fit this registered capture (with and without per-pixel refinement) and compare
    /// the maps with the ground truth of --truth. The light intensity is withheld from
    /// the fit (albedos are compared after one global scale factor).
    #[arg(long, requires = "truth")]
    fit_capture: Option<std::path::PathBuf>,
    /// With --fit-capture: write, per held-out light, truth | fit | 4 x |difference|
    /// as sRGB PNGs into this folder.
    #[arg(long, requires = "fit_capture")]
    fit_pictures: Option<std::path::PathBuf>,
    /// Compare the maps of an existing `svbrdf fit` output folder with --truth.
    #[arg(long, requires = "truth")]
    fit_maps: Option<std::path::PathBuf>,
    /// Score the true maps of --truth after a Gaussian blur of these widths (output
    /// pixels, comma-separated): the accuracy that perfect maps at a slightly lower
    /// resolution reach, one JSON line per width (`bench: resolution_floor`).
    #[arg(long, requires = "truth", value_delimiter = ',')]
    truth_blur: Vec<f64>,
    /// Settings file for --fit-capture (JSON subset of `FitConfig`).
    #[arg(long, requires = "fit_capture")]
    fit_config: Option<std::path::PathBuf>,
    /// Model for --fit-capture: ward or ggx.
    #[arg(long, default_value = "ward")]
    fit_model: String,
    /// Skip the BRDF throughput measurements.
    #[arg(long)]
    no_brdf: bool,
    /// Also time `synth --preset tiny` end to end (needs a writable temp folder).
    #[arg(long)]
    synth: bool,
    /// Run the whole pipeline (align, fit, export, report) on a simulated capture of
    /// this preset (`tiny` or `paper`) and print one JSON line: per-stage wall time and
    /// peak memory, alignment and pose errors, map errors and relighting error against
    /// the ground truth. The capture is synthesized into --dir, or reused from there.
    #[arg(long)]
    preset: Option<String>,
    /// Working folder of --preset: capture/ (reused when complete) and run/.
    #[arg(long, requires = "preset")]
    dir: Option<std::path::PathBuf>,
    /// With --preset: render the capture with a second, no-flash camera too (the
    /// `two-camera` preset always has one), run the pipeline with --second-video and
    /// again with the flash video alone (run-one-camera/), and report both.
    #[arg(long, requires = "preset")]
    second_video: bool,
    /// Held-out evaluation of a registered capture (e.g. `svbrdf import` of the real
    /// cards-blue photos): leave-k-out over every combination, with the diffuse-only
    /// baseline, into --eval-out; one JSON line with both means.
    #[arg(long)]
    eval_capture: Option<std::path::PathBuf>,
    /// Frames held out per fit for --eval-capture.
    #[arg(long, default_value_t = 2, requires = "eval_capture")]
    eval_leave_out: usize,
    /// Map resolution for --eval-capture, pixels per cm.
    #[arg(long, default_value_t = 40.0, requires = "eval_capture")]
    eval_px_per_cm: f64,
    /// Working folder for --eval-capture (finished sets are reused).
    #[arg(long, default_value = "bench-eval", requires = "eval_capture")]
    eval_out: std::path::PathBuf,
    /// Samples per BRDF measurement.
    #[arg(long, default_value_t = 4_000_000)]
    samples: usize,
}

pub(crate) fn machine() -> serde_json::Value {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .map(|l| l.split(':').nth(1).unwrap_or("").trim().to_string())
        })
        .unwrap_or_else(|| "unknown".into());
    json!({ "cpu": cpu, "threads": rayon::current_num_threads() })
}

fn observations(n: usize) -> Vec<LightView> {
    (0..n)
        .map(|i| {
            let f = i as f64;
            let s = Vec3::new((f * 0.37).sin() * 3.0, (f * 0.11).cos() * 3.0, 0.0);
            let cam = Vec3::new(
                (f * 0.013).sin() * 5.0,
                (f * 0.007).cos() * 5.0,
                12.0 + (f * 0.003).sin() * 4.0,
            );
            LightView::from_points(s, cam + Vec3::new(1.4, -0.3, 0.0), cam)
        })
        .collect()
}

/// Peak resident memory of this process (Linux `VmHWM`), kB.
pub fn peak_memory_kb() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// Start a new peak-memory measurement: Linux resets the process's VmHWM to its
/// current resident size when "5" is written to /proc/self/clear_refs.
pub fn reset_peak_memory() {
    crate::alloc::release_free_memory();
    let _ = std::fs::write("/proc/self/clear_refs", "5");
}

/// How many of the connections found by testing all pairs the predicted-overlap
/// search also found (both runs' `align.json`).
pub fn connectivity_recall(
    all_pairs_dir: &std::path::Path,
    predicted_dir: &std::path::Path,
) -> Result<serde_json::Value> {
    let load = |d: &std::path::Path| -> Result<(Vec<(u64, u64)>, f64)> {
        let v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(d.join("align.json"))?)?;
        let pairs = v["summary"]["verified_pairs"]
            .as_array()
            .map(|a| {
                a.iter()
                    .filter_map(|p| Some((p[0].as_u64()?, p[1].as_u64()?)))
                    .collect()
            })
            .unwrap_or_default();
        let coarse = v["summary"]["timings"]
            .as_array()
            .map(|a| {
                a.iter()
                    .filter(|t| t[0] == "coarse alignment")
                    .filter_map(|t| t[1].as_f64())
                    .sum()
            })
            .unwrap_or(f64::NAN);
        Ok((pairs, coarse))
    };
    let (all, t_all) = load(all_pairs_dir)?;
    let (pred, t_pred) = load(predicted_dir)?;
    let found = all.iter().filter(|p| pred.contains(p)).count();
    Ok(json!({
        "bench": "coarse_overlap_search",
        "all_pairs_connections": all.len(),
        "predicted_connections": pred.len(),
        "recall": found as f64 / all.len().max(1) as f64,
        "coarse_seconds_all_pairs": t_all,
        "coarse_seconds_predicted": t_pred,
    }))
}

/// The whole pipeline on a simulated capture of `preset`, measured against its truth.
pub fn pipeline(
    preset: &str,
    dir: &std::path::Path,
    second_video: bool,
) -> Result<serde_json::Value> {
    let mut cfg = svbrdf_synth::SynthConfig::preset(preset)?;
    if second_video && cfg.second_camera.is_none() {
        cfg.second_camera = Some(cfg.default_second_camera());
    }
    let two = cfg.second_camera.is_some();
    let capture = dir.join("capture");
    let complete = capture.join("ground_truth").join("truth.json").exists()
        && capture.join("flash.mp4").exists()
        && (!two || capture.join("second.mp4").exists());
    let synth_seconds = if complete {
        eprintln!("bench: reusing the capture in {}", capture.display());
        None
    } else {
        eprintln!(
            "bench: synthesizing the {preset} capture into {}",
            capture.display()
        );
        let t = Instant::now();
        svbrdf_cv::set_single_threaded()?;
        svbrdf_synth::synthesize(&cfg, &capture, true, &crate::progress::Bars::new())?;
        Some(t.elapsed().as_secs_f64())
    };
    let mut run_args = crate::run_cmd::RunArgs::for_synthetic_capture(
        &capture,
        dir.join("run"),
        cfg.map_px_per_cm,
    );
    if two {
        run_args.second = crate::SecondArgs {
            second_video: Some(capture.join("second.mp4")),
            second_camera: Some(capture.join("second_camera.json")),
            ..crate::SecondArgs::default()
        };
    }
    let t = Instant::now();
    let outcome = crate::run_cmd::run_pipeline(&run_args)?;
    // The comparison with the truth is the benchmark's, not the pipeline's.
    let pipeline_seconds =
        t.elapsed().as_secs_f64() - outcome.record["truth_seconds"].as_f64().unwrap_or(0.0);
    let aligned = run_args.out.join(crate::run_cmd::ALIGNED);
    let maps = run_args.out.join(crate::run_cmd::MAPS);
    let Some((align, acc)) = &outcome.truth else {
        anyhow::bail!("the pipeline did not compare with the truth");
    };
    let align_rec: serde_json::Value = svbrdf_core::fsutil::read_json(&aligned.join("align.json"))?;
    let fit_rec: serde_json::Value = svbrdf_core::fsutil::read_json(&maps.join("fit.json"))?;
    let stages = &outcome.record["stages"];
    let maps_figures = |acc: &svbrdf_fit::evaluate::Accuracy| {
        json!({
            "diffuse_rmse": acc.diffuse_rmse,
            "albedo_scale": acc.albedo_scale,
            "normal_mean_deg": acc.normal_mean_deg,
            "normal_median_deg": acc.normal_median_deg,
            "relight_relative_rmse_mean": acc.relight_relative_rmse_mean,
            "relight_relative_rmse": acc.relight_relative_rmse,
        })
    };
    // Two cameras: the same capture through the flash video alone, for comparison.
    let one_camera = if two {
        let one_args = crate::run_cmd::RunArgs::for_synthetic_capture(
            &capture,
            dir.join("run-one-camera"),
            cfg.map_px_per_cm,
        );
        let one = crate::run_cmd::run_pipeline(&one_args)?;
        let Some((_, acc1)) = &one.truth else {
            anyhow::bail!("the one-camera pipeline did not compare with the truth");
        };
        let f = maps_figures(acc1);
        json!({
            "relight_relative_rmse_mean_one_camera": f["relight_relative_rmse_mean"],
            "relight_relative_rmse_mean_two_cameras": acc.relight_relative_rmse_mean,
            "one_camera_maps": f,
        })
    } else {
        serde_json::Value::Null
    };
    Ok(json!({
        "bench": "pipeline",
        "preset": preset,
        "machine": machine(),
        "synth_seconds": synth_seconds,
        "pipeline_seconds": pipeline_seconds,
        "stages": {
            "align": {"seconds": stages["align"]["seconds"], "peak_memory_mb": stages["align"]["peak_memory_mb"], "timings": align_rec["summary"]["timings"]},
            "fit": {"seconds": stages["fit"]["seconds"], "peak_memory_mb": stages["fit"]["peak_memory_mb"], "timings": fit_rec["summary"]["timings"]},
            "export": {"seconds": stages["export"]["seconds"], "peak_memory_mb": stages["export"]["peak_memory_mb"]},
            "report": {"seconds": outcome.record["report_seconds"]},
        },
        "frames": align_rec["summary"]["frames"],
        "alignment": {
            "align_error_px_median": align["align_error_px_median"],
            "align_error_px_p95": align["align_error_px_p95"],
            "worst_frame_px_p95": align["worst_frame_px_p95"],
            "camera_error_mm_median": align["camera_error_mm_median"],
            "flash_error_mm_median": align["flash_error_mm_median"],
        },
        "maps": maps_figures(acc),
        "second_stream": align["second_stream"],
        "two_cameras": one_camera,
        "clusters": {"initial": fit_rec["summary"]["initial_clusters"], "final": fit_rec["summary"]["final_clusters"]},
    }))
}

pub fn run(a: &BenchArgs) -> Result<()> {
    crate::STDOUT_IS_JSON.store(true, std::sync::atomic::Ordering::Relaxed);
    if let Some(p) = &a.preset {
        let dir = a
            .dir
            .clone()
            .unwrap_or_else(|| std::path::PathBuf::from(format!("bench-{p}")));
        println!("{}", pipeline(p, &dir, a.second_video)?);
        if a.no_brdf {
            return Ok(());
        }
    }
    if let Some(c) = &a.eval_capture {
        let t = Instant::now();
        let args = crate::eval_cmd::EvalArgs {
            capture: c.clone(),
            holdout: None,
            leave_out: Some(a.eval_leave_out),
            out: a.eval_out.clone(),
            diffuse_only: false,
            baseline: true,
            fit: crate::fit_cmd::FitOptions {
                config: None,
                model: "ward".into(),
                px_per_cm: Some(a.eval_px_per_cm),
                light_intensity: None,
                no_refine: false,
                no_room_light: false,
                seed: None,
                select_folds: None,
            },
            flip: None,
            overwrite: false,
        };
        let s = crate::eval_cmd::run_eval(&args)?;
        println!(
            "{}",
            json!({
                "bench": "holdout_eval",
                "capture": c.display().to_string(),
                "leave_out": a.eval_leave_out,
                "px_per_cm": a.eval_px_per_cm,
                "sets": s["sets"],
                "full": s["full"]["mean"],
                "diffuse_only": s["diffuse_only"]["mean"],
                "full_wins": s["pairwise"]["full_wins"],
                "flip_metric": s["flip_metric"],
                "fit_seconds_mean": s["full"]["fit_seconds_mean"],
                "seconds": t.elapsed().as_secs_f64(),
                "machine": machine(),
            })
        );
        if a.no_brdf {
            return Ok(());
        }
    }
    if let Some(sigma) = a.truth_blur.iter().find(|s| !(0.0..=10.0).contains(*s)) {
        anyhow::bail!("--truth-blur {sigma}: expected widths in [0, 10] pixels");
    }
    if let (false, Some(t)) = (a.truth_blur.is_empty(), &a.truth) {
        let truth = load_truth(t)?;
        for &sigma in &a.truth_blur {
            let acc = svbrdf_fit::evaluate::blurred_truth(&truth, sigma);
            println!(
                "{}",
                json!({"bench": "resolution_floor", "truth": t.display().to_string(), "sigma_px": sigma, "accuracy": acc})
            );
        }
        if a.no_brdf && a.fit_maps.is_none() && a.fit_capture.is_none() && a.align_capture.is_none()
        {
            return Ok(());
        }
    }
    if let (Some(m), Some(t)) = (&a.fit_maps, &a.truth) {
        let (acc, by_confidence, by_material) = maps_accuracy(m, t)?;
        println!(
            "{}",
            json!({
                "bench": "maps_accuracy",
                "maps": m.display().to_string(),
                "accuracy": acc,
                "relight_by_specular_confidence": by_confidence,
                "relight_by_true_material": by_material,
            })
        );
        if a.no_brdf && a.fit_capture.is_none() && a.align_capture.is_none() {
            return Ok(());
        }
    }
    if let (Some(c), Some(t)) = (&a.fit_capture, &a.truth) {
        for v in fit_accuracy(
            c,
            t,
            &a.fit_model,
            a.fit_config.as_deref(),
            a.fit_pictures.as_deref(),
        )? {
            println!("{v}");
        }
        if a.no_brdf && a.align_capture.is_none() {
            return Ok(());
        }
    }
    if let (Some(c), Some(t)) = (&a.align_capture, &a.truth) {
        let mut v = align_accuracy(c, t)?;
        if let Ok(text) = std::fs::read_to_string(c.join("align.json")) {
            if let Ok(rec) = serde_json::from_str::<serde_json::Value>(&text) {
                v["timings"] = rec["summary"]["timings"].clone();
                v["frames"] = rec["summary"]["frames"].clone();
            }
        }
        v["machine"] = machine();
        println!("{v}");
        if let Some(all) = &a.all_pairs_capture {
            println!("{}", connectivity_recall(all, c)?);
        }
        if a.no_brdf {
            return Ok(());
        }
    }
    let obs = observations(a.samples);
    let p = Prepared::new(BrdfParams {
        alpha_x: 0.15,
        alpha_y: 0.3,
        normal_theta_x: 0.1,
        normal_theta_y: -0.05,
        ..BrdfParams::default()
    });
    for kind in [ModelKind::Ward, ModelKind::Ggx] {
        let m = kind.model();
        for grad in [false, true] {
            let t = Instant::now();
            let sum: f64 = obs
                .par_chunks(4096)
                .map(|c| {
                    c.iter()
                        .map(|o| {
                            if grad {
                                m.radiance_grad(&p, o, 300.0).d_shared[0][0]
                            } else {
                                m.radiance(&p, o, 300.0)[0]
                            }
                        })
                        .sum::<f64>()
                })
                .sum();
            let secs = t.elapsed().as_secs_f64();
            println!(
                "{}",
                json!({
                    "bench": if grad { "brdf_radiance_grad" } else { "brdf_radiance" },
                    "model": m.name(),
                    "samples": a.samples,
                    "seconds": secs,
                    "msamples_per_s": a.samples as f64 / secs / 1e6,
                    "checksum": sum,
                    "machine": machine(),
                })
            );
        }
    }
    if a.synth {
        let dir = std::env::temp_dir().join(format!("svbrdf-bench-{}", std::process::id()));
        let cfg = svbrdf_synth::SynthConfig::tiny();
        let t = Instant::now();
        let s = svbrdf_synth::synthesize(&cfg, &dir, true, &svbrdf_synth::NoProgress)?;
        let secs = t.elapsed().as_secs_f64();
        let _ = std::fs::remove_dir_all(&dir);
        println!(
            "{}",
            json!({
                "bench": "synth_tiny",
                "frames": s.frames,
                "width": cfg.video.width,
                "height": cfg.video.height,
                "seconds": secs,
                "frames_per_s": s.frames as f64 / secs,
                "machine": machine(),
            })
        );
    }
    Ok(())
}
