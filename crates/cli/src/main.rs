//! `svbrdf`: capture spatially varying BRDFs of flat materials with a phone.
//!
//! The binary only parses, validates and calls library stages; it owns progress bars
//! and prints errors once.

/// Whether stdout is reserved for JSON (`svbrdf bench`): progress messages of the
/// stages then go to stderr.
static STDOUT_IS_JSON: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// `println!` for human-readable progress, or `eprintln!` while stdout carries JSON.
macro_rules! say {
    ($($t:tt)*) => {
        if crate::STDOUT_IS_JSON.load(std::sync::atomic::Ordering::Relaxed) {
            eprintln!($($t)*)
        } else {
            println!($($t)*)
        }
    };
}

mod accuracy;
mod bench;
mod fit_cmd;
mod progress;
mod synth_cmd;

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::{Args, Parser, Subcommand};

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
    Synth(synth_cmd::SynthArgs),
    /// Synthesize a small capture of a built-in material and report what was written.
    Demo(synth_cmd::DemoArgs),
    /// Align a flash video to the plane defined by the markers in a reference photo and
    /// write a registered capture (paper section 3.1).
    Align(AlignArgs),
    /// Compare every frame of a registered capture with the reference photo (the
    /// self-check `align` runs before it writes) and name the frames that disagree.
    Check(CheckArgs),
    /// Fit svBRDF maps (diffuse, specular, roughness, normal) to a registered capture
    /// (paper section 3.2) and check them by re-rendering every frame.
    Fit(fit_cmd::FitArgs),
    /// The whole pipeline: align, fit, export and report, reusing finished stages.
    Run(run_cmd::RunArgs),
    /// Export fitted maps as a glTF 2.0 material and a Mitsuba 3 scene.
    Export(run_cmd::ExportArgs),
    /// Show the exported material in a local web page (three.js) with a light you drag.
    View(view::ViewArgs),
    /// Write the printable marker sheet of the capture kit (SVG and 300 dpi PNG).
    Markers(run_cmd::MarkersArgs),
    /// Measure speed and accuracy and print one JSON object per line.
    Bench(bench::BenchArgs),
    /// Convert a registered image set from another tool (MaterialGAN layout) into a
    /// registered capture for `fit`, `run --capture` and `eval`.
    Import(eval_cmd::ImportArgs),
    /// Fit without some frames and compare renderings of them with the photos (RMSE
    /// and SSIM, linear and sRGB; strips; report).
    Eval(eval_cmd::EvalArgs),
}

#[derive(Args)]
#[command(allow_negative_numbers = true)]
struct CheckArgs {
    /// The registered capture folder (holding capture.json).
    #[arg(long)]
    capture: PathBuf,
    /// The reference photo whose markers define the plane.
    #[arg(long)]
    reference: PathBuf,
    /// The phone's camera description (JSON); default: the kit's phone.
    #[arg(long)]
    camera: Option<PathBuf>,
    /// Offset from the reference photo beyond which a frame is named, mm (default 1).
    #[arg(long)]
    limit_mm: Option<f64>,
}

#[derive(Args, Clone)]
#[command(allow_negative_numbers = true)]
struct AlignArgs {
    /// The flash video (any container and codec FFmpeg decodes; rotation metadata is applied).
    #[arg(long, required_unless_present = "photos")]
    video: Option<PathBuf>,
    /// Instead of a video: a folder of flash photos (JPEG/PNG, EXIF orientation
    /// applied). Photos have no time order (overlaps are found by matching every pair)
    /// and no blur pre-filter.
    #[arg(long, conflicts_with_all = ["video", "second_video"])]
    photos: Option<PathBuf>,
    /// The reference photo showing all four markers (JPEG/PNG).
    #[arg(long)]
    reference: PathBuf,
    /// Phone description (JSON: fov_deg, flash_offset_cm, marker_size_cm,
    /// marker_dictionary, frame_step). Missing fields take the paper's values:
    /// 70 degrees, [1.4, -0.3, 0] cm, 1.6 cm, DICT_6X6_250, every 5th frame.
    #[arg(long)]
    camera: Option<PathBuf>,
    /// Output folder for the registered capture.
    #[arg(long)]
    out: PathBuf,
    /// Output region on the plane as x_min,x_max,y_min,y_max in cm (default: bounded
    /// by the markers' inner corners).
    #[arg(long, value_delimiter = ',', num_args = 1..=4, allow_hyphen_values = true)]
    region: Option<Vec<f64>>,
    /// Output resolution in pixels per cm (default: half the frames' sampling density).
    #[arg(long)]
    px_per_cm: Option<f64>,
    /// How fine correspondences are found: `patch` (default: coarse SIFT matches
    /// refined at full resolution by patch correlation) or `sift` (the paper's: SIFT at
    /// full resolution, slower and less precise).
    #[arg(long, value_parser = ["patch", "sift"])]
    fine_method: Option<String>,
    /// Long side, in pixels, of the images used for fine matching (default 3840: full
    /// resolution for 4K video; lower is faster and less precise).
    #[arg(long)]
    fine_long_side: Option<u32>,
    /// Fine SIFT features per frame with `--fine-method sift` (default 12000, the
    /// paper's).
    #[arg(long)]
    fine_features: Option<usize>,
    /// Minimum fine inliers per frame pair (default 60, the paper's).
    #[arg(long)]
    fine_min_inliers: Option<usize>,
    /// Fine homography inlier distance in pixels at a 3840-pixel long side, scaled with
    /// resolution (default 60, the paper's).
    #[arg(long)]
    fine_inlier_px: Option<f64>,
    /// A frame pair's patch-refined matches farther than this from one homography
    /// fitted to them are dropped, pixels at a 3840-pixel long side, scaled (default 8;
    /// catches matches a period off on repetitive texture; a large value turns it off).
    #[arg(long)]
    fine_recheck_px: Option<f64>,
    /// Where a sub-frame of either frame of a pair has fewer patch-refined matches than
    /// this, the pair's other features there are predicted through the pair's
    /// homography and refined (default 8; 0 turns it off; helps flat repetitive texture
    /// such as plain tiles, whose alike features the ratio test rejects; not used with
    /// a second video nor on frames or photos over 1920 pixels on their long side;
    /// docs/RELIABILITY.md).
    #[arg(long)]
    fine_fill: Option<usize>,
    /// Sub-frame grid as COLSxROWS (default: the paper's 5x11 at 2160x3840, scaled).
    #[arg(long)]
    subframes: Option<String>,
    /// Weight of agreement between neighbouring sub-frames where they overlap, relative
    /// to one feature match (default 4).
    #[arg(long)]
    overlap_weight: Option<f64>,
    /// Largest noise gain a sub-frame's map may have and still be used (default 4):
    /// larger keeps sub-frames that no correspondence of their own fixes, whose maps
    /// are extrapolations (docs/RELIABILITY.md).
    #[arg(long)]
    max_noise_gain: Option<f64>,
    /// Largest noise gain at which a sub-frame on a frame's edge is used out to that
    /// edge (default 1.5; 0: always): beyond it the map is cut back towards where its
    /// correspondences fix it.
    #[arg(long)]
    edge_noise_gain: Option<f64>,
    /// Test all frame pairs in coarse alignment (slow; for benchmarks).
    #[arg(long)]
    all_pairs: bool,
    /// Take every flash frame as recorded at the same exposure instead of estimating
    /// one gain per frame from overlapping frames (for captures with exposure locked).
    #[arg(long)]
    fixed_exposure: bool,
    /// Skip the check of every registered frame against the reference photo (frames
    /// that disagree are then kept, and nothing refuses a drifted registration).
    #[arg(long)]
    no_self_check: bool,
    /// Fine-match each frame with at most this many of its strongest coarse connections
    /// (the time chain is always kept); default 8.
    #[arg(long)]
    max_pairs_per_frame: Option<usize>,
    /// Use the sharpest frame within this many frames of every `frame_step`-th one
    /// (default 1: the sharpest of three; 0: the paper's fixed sampling).
    #[arg(long)]
    sharpest_within: Option<u32>,
    /// Views of each marker wanted among the registered frames (default 2): where the
    /// sampled frames show a marker whole fewer times, every other frame is searched for
    /// it and the sharpest of each pass over it added; 0 turns this marker hunt off.
    #[arg(long)]
    marker_views: Option<u32>,
    /// Do not match frames with the reference photo: only markers tie frames to the
    /// plane (a diagnostic: what alignment does where the reference photo cannot be
    /// matched, e.g. under very different light).
    #[arg(long)]
    no_reference_matches: bool,
    /// Do not tie frames without reference-photo matches of their own to the plane by
    /// the blocks the self-check matched with the reference photo (a diagnostic)
    #[arg(long)]
    no_plane_ties: bool,
    /// Do not look for the corners of markers that detection missed in a frame (cut by
    /// the frame's edge, or blurred) where the frame's map puts them (a diagnostic)
    #[arg(long)]
    no_marker_corners: bool,
    /// Do not measure or correct the relief shift (the texture of a material with
    /// relief appears moved towards the flash; a diagnostic)
    #[arg(long)]
    no_relief: bool,
    /// Do not align the video again from every `frame_step / 2`-th frame where the
    /// frames sampled at the camera's `frame_step` leave the region thin or are refused
    #[arg(long)]
    no_densify: bool,
    #[command(flatten)]
    second: SecondArgs,
    /// Replace the output folder if it exists.
    #[arg(long)]
    overwrite: bool,
}

/// The second phone of a two-camera capture (paper section 3.3).
#[derive(Args, Clone, Default)]
#[command(allow_negative_numbers = true)]
pub struct SecondArgs {
    /// A second, no-flash video filmed from an oblique angle while the flash video was
    /// recorded; it must start before the flash video (the flash onset synchronises the
    /// two) and stop before it.
    #[arg(long)]
    pub second_video: Option<PathBuf>,
    /// The second phone's description (JSON, as --camera; `frame_step` is the second
    /// stream's, `readout_s` its rolling-shutter readout in seconds, 0 if unknown).
    /// Missing fields: 70 degrees, every 10th frame (the paper's two-camera setting).
    #[arg(long)]
    pub second_camera: Option<PathBuf>,
    /// Time, in seconds on the second video's clock, of the flash video's first frame
    /// (default: found from the flash onset).
    #[arg(long)]
    pub sync_offset: Option<f64>,
    /// Drop second-video frames recorded after the flash video ended instead of
    /// refusing the capture.
    #[arg(long)]
    pub trim_second: bool,
}

fn align_config(a: &AlignArgs) -> Result<svbrdf_align::AlignConfig> {
    let mut c = svbrdf_align::AlignConfig::default();
    if let Some(p) = &a.camera {
        c.camera = svbrdf_align::CameraDescription::load(p)?;
    }
    if let Some(r) = &a.region {
        anyhow::ensure!(
            r.len() == 4,
            "invalid region {} (expected four numbers in cm: x_min,x_max,y_min,y_max)",
            r.iter().map(f64::to_string).collect::<Vec<_>>().join(",")
        );
        c.region = Some(svbrdf_core::plane::Region {
            x_min: r[0],
            x_max: r[1],
            y_min: r[2],
            y_max: r[3],
        });
    }
    c.px_per_cm = a.px_per_cm;
    if let Some(m) = &a.fine_method {
        c.fine_method = match m.as_str() {
            "sift" => svbrdf_align::FineMethod::Sift,
            _ => svbrdf_align::FineMethod::Patch,
        };
    }
    if let Some(v) = a.fine_long_side {
        c.fine_long_side = v;
    }
    if let Some(v) = a.overlap_weight {
        c.overlap_weight = v;
    }
    if let Some(v) = a.max_noise_gain {
        c.max_noise_gain = v;
    }
    if let Some(v) = a.edge_noise_gain {
        c.edge_noise_gain = v;
    }
    if let Some(v) = a.marker_views {
        c.marker_views = v;
    }
    if a.no_reference_matches {
        c.match_reference = false;
    }
    if a.no_marker_corners {
        c.marker_corners = false;
    }
    if a.no_relief {
        c.relief = false;
    }
    if a.no_plane_ties {
        c.plane_ties = false;
    }
    if a.no_densify {
        c.densify = false;
    }

    if let Some(v) = a.fine_features {
        c.fine_features = v;
    }
    if let Some(v) = a.fine_min_inliers {
        c.fine_min_inliers = v;
    }
    if let Some(v) = a.fine_inlier_px {
        c.fine_inlier_px = v;
    }
    if let Some(v) = a.fine_recheck_px {
        c.fine_recheck_px = v;
    }
    if let Some(v) = a.fine_fill {
        c.fine_fill = v;
    }
    if let Some(s) = &a.subframes {
        let parts: Vec<&str> = s.split(['x', 'X']).collect();
        let parsed = match parts.as_slice() {
            [c, r] => c.parse::<u32>().ok().zip(r.parse::<u32>().ok()),
            _ => None,
        };
        c.subframes = Some(parsed.ok_or_else(|| {
            anyhow::anyhow!("invalid sub-frame grid {s:?} (expected COLSxROWS, e.g. 5x11)")
        })?);
    }
    c.all_pairs = a.all_pairs;
    c.fixed_exposure = a.fixed_exposure;
    c.self_check.enabled = !a.no_self_check;
    if let Some(v) = a.max_pairs_per_frame {
        c.max_pairs_per_frame = v;
    }
    if let Some(v) = a.sharpest_within {
        c.sharpest_within = v;
    }
    if let Some(p) = &a.second.second_camera {
        // Missing fields take the paper's two-camera values, not the flash phone's.
        // Unknown keys are refused (a typo must not fall back to a default).
        svbrdf_core::fsutil::read_json_settings::<svbrdf_align::CameraDescription>(p)?;
        let raw: serde_json::Value = svbrdf_core::fsutil::read_json(p)?;
        let mut merged = serde_json::to_value(&c.second_camera)?;
        if let (Some(m), Some(r)) = (merged.as_object_mut(), raw.as_object()) {
            for (k, v) in r {
                m.insert(k.clone(), v.clone());
            }
        }
        c.second_camera =
            serde_json::from_value(merged).with_context(|| format!("reading {}", p.display()))?;
        c.second_camera
            .validate()
            .with_context(|| format!("in {}", p.display()))?;
    } else {
        // The same phone model as the flash video, at the paper's two-camera step.
        c.second_camera = svbrdf_align::CameraDescription {
            frame_step: c.second_camera.frame_step,
            ..c.camera.clone()
        };
    }
    c.sync_offset_s = a.second.sync_offset;
    c.trim_second = a.second.trim_second;
    c.validate()?;
    Ok(c)
}

/// `svbrdf check`: one JSON line with every frame's check on stdout, a summary line,
/// and an error naming the frames that disagree.
fn run_check(a: &CheckArgs) -> Result<()> {
    let mut cfg = svbrdf_align::AlignConfig::default();
    if let Some(p) = &a.camera {
        cfg.camera = svbrdf_align::CameraDescription::load(p)?;
    }
    if let Some(v) = a.limit_mm {
        cfg.self_check.max_shift_mm = v;
    }
    svbrdf_cv::set_single_threaded()?;
    let progress = progress::Bars::new();
    let c = svbrdf_align::recheck::check_capture(&a.capture, &a.reference, &cfg, &progress)?;
    let bad = c.inconsistent();
    println!(
        "{}",
        serde_json::json!({
            "check": "self_check",
            "capture": a.capture.display().to_string(),
            "limit_mm": c.limit_mm,
            "inconsistent": bad,
            "unverified": c.unverified(),
            "frames": c.frames,
        })
    );
    let (checked, largest) = svbrdf_align::selfcheck::verified(&c.frames);
    say!(
        "self-check against the reference photo: {} of {} frames verified, largest median offset {:.2} mm",
        checked,
        c.frames.len(),
        largest
    );
    if let Some(what) = svbrdf_align::selfcheck::disagreement(&c.frames, c.limit_mm) {
        anyhow::bail!(
            "{what} (expected at most {} mm): their mapping is wrong; align again, or drop them from capture.json",
            c.limit_mm
        );
    }
    Ok(())
}

fn run_align(a: &AlignArgs) -> Result<()> {
    let cfg = align_config(a)?;
    let settings: Vec<PathBuf> = [&a.camera, &a.second.second_camera]
        .into_iter()
        .flatten()
        .cloned()
        .collect();
    svbrdf_core::fsutil::check_output_spares_inputs(&a.out, &settings)?;
    svbrdf_cv::set_single_threaded()?;
    alloc::retain_freed_pages(true);
    let progress = progress::Bars::new();
    let inputs = svbrdf_align::AlignInputs {
        video: a.video.clone(),
        photos: a.photos.clone(),
        reference: a.reference.clone(),
        second_video: a.second.second_video.clone(),
    };
    let s = svbrdf_align::align(&inputs, &cfg, &a.out, a.overwrite, &progress)?;
    let f = &s.frames;
    say!("wrote {}", s.out.display());
    if let Some(d) = &s.densified {
        say!("{}", d.describe());
    }
    say!("frames: {}", f.describe());
    say!(
        "matching: {} coarse pairs tested, {} connected, {} fine pairs{}{}; {} frames see markers, {} anchored to the reference photo{}",
        s.coarse_pairs_tested, s.connected_pairs, s.fine_pairs,
        if s.fine_matches_rechecked > 0 { format!(" ({} refined matches dropped as off their pair's homography)", s.fine_matches_rechecked) } else { String::new() },
        if s.fine_matches_guided > 0 { format!(", {} matches found guided by their pair's homography", s.fine_matches_guided) } else { String::new() },
        s.frames_with_markers, s.reference_anchored,
        if s.pieces > 1 { format!("; the frames form {} pieces, each tied to the plane by the reference photo or markers", s.pieces) } else { String::new() }
    );
    if let Some(v) = &s.video_decoding {
        say!(
            "video: {} {}, matrix {}, range {}: decoded with {}, transfer {}{}, {} bits kept ({})",
            v.codec,
            v.pix_fmt,
            v.matrix_tag.as_deref().unwrap_or("untagged"),
            v.range_tag
                .as_deref()
                .unwrap_or("untagged (limited assumed)"),
            v.decoded_with.label(),
            v.transfer.label(),
            if v.from_bt2020 {
                ", BT.2020 primaries converted to BT.709"
            } else {
                ""
            },
            if v.decoder == "opencv" {
                8
            } else {
                v.bit_depth
            },
            v.decoder
        );
    }
    if let Some(h) = &s.marker_hunt {
        say!("{}", h.describe());
    }
    if let Some(t) = &s.plane_ties {
        say!("{}", t.describe());
    }
    if let Some(m) = &s.marker_corners {
        say!("{}", m.describe());
    }
    if let Some(r) = &s.relief {
        say!("{}", r.describe());
    }
    if let Some(line) = s.support.describe() {
        say!("support: {line}");
    }
    if let Some(t) = &s.second {
        say!("second video: {}", t.describe());
    }
    if let Some(e) = &s.exposure {
        say!("{}", e.describe());
    }
    let (checked, worst) = svbrdf_align::selfcheck::verified(&s.self_check);
    say!(
        "coverage: {:.1}% of the region seen by at least {} kept frames; self-check against the reference photo: {} of {} frames verified, largest median offset {:.2} mm",
        100.0 * s.coverage,
        svbrdf_align::COVERAGE_VIEWS,
        checked,
        s.self_check.len(),
        worst
    );
    say!(
        "global solve: {} unknowns, {} iterations (+{} reusing a factorisation), residual rms {:.4} cm, median {:.4} cm",
        s.unknowns,
        s.solve_iterations,
        s.solve_cheap_steps,
        s.solve_rms_cm,
        s.solve_median_cm
    );
    print_timings(&s.timings);
    print_warnings(&s.warnings);
    Ok(())
}

/// Doubts about the input or the result: once each, on stderr.
pub fn print_warnings(warnings: &[String]) {
    for w in warnings {
        eprintln!("warning: {w}");
    }
}

/// Stage timings and the process's peak memory, one line each.
pub fn print_timings(timings: &[(String, f64)]) {
    let t: Vec<String> = timings
        .iter()
        .map(|(n, v)| format!("{n} {v:.1} s"))
        .collect();
    say!("timings: {}", t.join(", "));
    if let Some(kb) = bench::peak_memory_kb() {
        say!("peak memory: {:.0} MB", kb as f64 / 1024.0);
    }
}

mod alloc;
mod eval_cmd;
mod flip;
mod run_cmd;
mod view;

fn main() -> ExitCode {
    // `svbrdf bench | head -1` closes our stdout early; Rust then panics inside
    // `println!`. End quietly with the shell's broken-pipe status instead.
    let default_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let payload = info.payload();
        let msg = payload
            .downcast_ref::<String>()
            .map(String::as_str)
            .or_else(|| payload.downcast_ref::<&str>().copied())
            .unwrap_or("");
        if msg.contains("failed printing to stdout") && msg.contains("Broken pipe") {
            std::process::exit(141);
        }
        default_hook(info);
    }));
    // FFmpeg's own log lines (through OpenCV) would come before ours and say less.
    if std::env::var_os("OPENCV_FFMPEG_LOGLEVEL").is_none() {
        std::env::set_var("OPENCV_FFMPEG_LOGLEVEL", "-8");
    }
    let cli = match Cli::try_parse() {
        Ok(c) => c,
        Err(e) if !e.use_stderr() => {
            // --help and --version.
            let _ = e.print();
            return ExitCode::SUCCESS;
        }
        Err(e) if e.kind() == clap::error::ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand => {
            let _ = e.print();
            return ExitCode::from(2);
        }
        Err(e) => {
            // One line: clap's message and its hint of valid values, without the usage
            // block (`--help` shows that).
            let text = e.render().to_string();
            let line: Vec<&str> = text
                .lines()
                .map(str::trim)
                .filter(|l| {
                    !l.is_empty()
                        && !l.starts_with("Usage:")
                        && !l.starts_with("For more information")
                })
                .collect();
            eprintln!("{}", line.join(" "));
            return ExitCode::from(2);
        }
    };
    let result = match cli.command {
        Command::Synth(a) => synth_cmd::run(&a),
        Command::Demo(a) => synth_cmd::run_demo(&a),
        Command::Align(a) => run_align(&a),
        Command::Check(a) => run_check(&a),
        Command::Fit(a) => fit_cmd::run_fit(&a).map(|_| ()),
        Command::Run(a) => run_cmd::run_pipeline(&a).and_then(|o| run_cmd::print_run_summary(&o)),
        Command::Export(a) => run_cmd::run_export(&a).map(|_| ()),
        Command::View(a) => view::run_view(&a),
        Command::Markers(a) => run_cmd::run_markers(&a),
        Command::Bench(a) => bench::run(&a),
        Command::Import(a) => eval_cmd::run_import(&a).map(|_| ()),
        Command::Eval(a) => eval_cmd::run_eval(&a).map(|_| ()),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
