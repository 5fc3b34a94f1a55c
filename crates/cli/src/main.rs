//! `svbrdf`: capture spatially varying BRDFs of flat materials with a phone.
//!
//! The binary only parses, validates and calls library stages; it owns progress bars
//! and prints errors once.

mod bench;
mod progress;

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::{Args, Parser, Subcommand};
use svbrdf_synth::{synthesize, MaterialSource, SynthConfig};

#[derive(Parser)]
#[command(
    name = "svbrdf",
    version,
    about = "Capture spatially varying BRDFs of flat materials with a phone flash video (Albert et al., EGSR 2018)."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render a synthetic phone capture with exact ground truth (reference photo,
    /// flash video, maps, cameras, held-out relighting, registered capture).
    Synth(SynthArgs),
    /// Synthesize a small capture of a built-in material and report what was written.
    Demo(DemoArgs),
    /// Measure speed of the hot paths and print one JSON object per line.
    Bench(bench::BenchArgs),
}

#[derive(Args)]
#[command(allow_negative_numbers = true)]
struct SynthArgs {
    /// Output folder (must not exist unless --overwrite).
    #[arg(long)]
    out: PathBuf,
    /// Preset: `tiny` (270x480, 3 s, 6x6 cm; seconds to render) or `paper`
    /// (2160x3840 at 30 fps, 20 s, 20x20 cm, 100 px/cm maps; the paper's setting).
    #[arg(long, default_value = "tiny")]
    preset: String,
    /// Random seed; the output is deterministic for a seed.
    #[arg(long)]
    seed: Option<u64>,
    /// Built-in material: patchwork, leather, brushed-metal or tiles.
    #[arg(long, conflicts_with = "maps")]
    material: Option<String>,
    /// Folder of map images to use as the material: diffuse (sRGB PNG/JPEG or linear
    /// EXR), optional specular, roughness (R = alpha_x, G = alpha_y), normal (OpenGL).
    #[arg(long)]
    maps: Option<PathBuf>,
    /// Video frame rate, frames per second (> 0). Default: the preset's (30).
    #[arg(long)]
    fps: Option<f64>,
    /// Video length, seconds (> 0).
    #[arg(long)]
    duration: Option<f64>,
    /// Field of view across the longer image side, degrees, in (0, 180). Default 70.
    #[arg(long)]
    fov: Option<f64>,
    /// Closest camera height above the surface during the sweep, cm (> 0).
    #[arg(long)]
    distance_min: Option<f64>,
    /// Farthest camera height, cm (>= --distance-min).
    #[arg(long)]
    distance_max: Option<f64>,
    /// Also render a second, no-flash camera at an oblique angle (paper section 3.3).
    #[arg(long)]
    second_camera: bool,
    /// Replace the output folder if it exists.
    #[arg(long)]
    overwrite: bool,
}

#[derive(Args)]
struct DemoArgs {
    /// Output folder.
    #[arg(long, default_value = "demo-out")]
    out: PathBuf,
}

fn synth_config(a: &SynthArgs) -> Result<SynthConfig> {
    let mut c = SynthConfig::preset(&a.preset)?;
    if let Some(s) = a.seed {
        c.seed = s;
    }
    if let Some(m) = &a.material {
        c.material = MaterialSource::Procedural(m.clone());
    }
    if let Some(p) = &a.maps {
        c.material = MaterialSource::Maps(p.clone());
    }
    if let Some(v) = a.fps {
        c.video.fps = v;
    }
    if let Some(v) = a.duration {
        c.video.duration_s = v;
    }
    if let Some(v) = a.fov {
        c.video.fov_deg = v;
    }
    if let Some(v) = a.distance_min {
        c.sweep.distance_min_cm = v;
    }
    if let Some(v) = a.distance_max {
        c.sweep.distance_max_cm = v;
    }
    if a.second_camera {
        c.second_camera = Some(c.default_second_camera());
    }
    c.validate()?;
    Ok(c)
}

fn run_synth(
    cfg: &SynthConfig,
    out: &std::path::Path,
    overwrite: bool,
) -> Result<svbrdf_synth::SynthSummary> {
    svbrdf_cv::set_single_threaded()?;
    let progress = progress::Bars::new();
    let summary = synthesize(cfg, out, overwrite, &progress)
        .with_context(|| format!("synthesizing into {}", out.display()))?;
    let t: Vec<String> = progress
        .timings()
        .iter()
        .map(|(n, s)| format!("{n} {s:.1} s"))
        .collect();
    println!("timings: {}", t.join(", "));
    Ok(summary)
}

fn print_summary(s: &svbrdf_synth::SynthSummary) {
    println!("wrote {}", s.out.display());
    for f in &s.files {
        println!("  {f}");
    }
    println!(
        "flash video: {} frames, {} with a marker fully visible, {} motion-blurred",
        s.frames, s.frames_with_markers, s.blurred_frames
    );
    if let Some(n) = s.second_frames {
        println!("second camera: {n} frames");
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Synth(a) => synth_config(&a)
            .and_then(|cfg| run_synth(&cfg, &a.out, a.overwrite))
            .map(|s| print_summary(&s)),
        Command::Demo(a) => {
            let cfg = SynthConfig::tiny();
            run_synth(&cfg, &a.out, true).map(|s| {
                print_summary(&s);
                println!("next: the alignment and fitting stages will run on this capture once they exist;");
                println!("      the ground-truth registered capture is in {}/registered/", s.out.display());
            })
        }
        Command::Bench(a) => bench::run(&a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
