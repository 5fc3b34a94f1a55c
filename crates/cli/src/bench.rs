//! `svbrdf bench`: hot-path throughput as JSON lines (one object per measurement), so
//! figures can be compared across commits on the same machine.

use std::time::Instant;

use anyhow::Result;
use clap::Args;
use rayon::prelude::*;
use serde_json::json;
use svbrdf_core::brdf::{BrdfParams, LightView, ModelKind, Prepared};
use svbrdf_core::geometry::Vec3;

#[derive(Args)]
pub struct BenchArgs {
    /// Also time `synth --preset tiny` end to end (needs a writable temp folder).
    #[arg(long)]
    synth: bool,
    /// Samples per BRDF measurement.
    #[arg(long, default_value_t = 4_000_000)]
    samples: usize,
}

fn machine() -> serde_json::Value {
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

pub fn run(a: &BenchArgs) -> Result<()> {
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
