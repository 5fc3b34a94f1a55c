//! `svbrdf run` (align, fit, export and report with stage reuse) and `svbrdf export`.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Args;
use serde_json::{json, Value};
use svbrdf_core::brdf::ModelKind;
use svbrdf_export::{ExportConfig, MaterialMaps};

/// Folder names inside a run's output folder.
pub const ALIGNED: &str = "aligned";
/// Fit output.
pub const MAPS: &str = "maps";
/// Exports.
pub const EXPORT: &str = "export";
/// The run's record of inputs, settings and finished stages.
pub const RUN_FILE: &str = "run.json";
const RUN_FORMAT: &str = "svbrdf-run";

#[derive(Args, Clone)]
pub struct ExportArgs {
    /// A fit output folder (holding fit.json and maps/).
    #[arg(long)]
    pub maps: PathBuf,
    /// Output folder; gets gltf/ (material.gltf + textures) and mitsuba/ (scene.xml).
    #[arg(long)]
    pub out: PathBuf,
    /// Material name inside the files (letters, digits, '_' and '-').
    #[arg(long, default_value = "svbrdf_material")]
    pub name: String,
    /// Leave out the preview sphere (the quad alone).
    #[arg(long)]
    pub no_sphere: bool,
    /// Cut the parts of the material no frame saw out of the glTF (alpha mask) instead
    /// of showing the BRDF filled in from the nearest measured cluster there.
    #[arg(long)]
    pub mask_unobserved: bool,
    /// Replace existing export folders.
    #[arg(long)]
    pub overwrite: bool,
}

/// The `run.json` of a run folder, if it holds one of ours.
pub fn run_record(dir: &Path) -> Option<Value> {
    let p = dir.join(RUN_FILE);
    if !p.is_file() {
        return None;
    }
    let v: Value = svbrdf_core::fsutil::read_json(&p).ok()?;
    (v["format"] == RUN_FORMAT).then_some(v)
}

/// Refuse a run folder whose last `run` did not finish: its stage folders may mix two
/// captures. (Records written before `complete` existed count as finished.)
pub fn refuse_unfinished_run(dir: &Path) -> Result<()> {
    if let Some(r) = run_record(dir) {
        if r["complete"] == json!(false) {
            let missing: Vec<&str> = ["align", "fit", "export"]
                .into_iter()
                .filter(|s| r["stages"][*s].is_null())
                .collect();
            anyhow::bail!(
                "unfinished run folder {} (its last `svbrdf run` stopped before {}; expected a finished run: run the same `svbrdf run ... --out {}` again to resume it)",
                dir.display(),
                if missing.is_empty() { "the report".to_string() } else { format!("finishing {}", missing.join(", ")) },
                dir.display()
            );
        }
    }
    Ok(())
}

/// Refuse the `maps/` of a run folder whose fit stage has not finished.
fn refuse_unfinished_maps(maps: &Path) -> Result<()> {
    let resolved = svbrdf_core::fsutil::resolve(maps);
    if resolved.file_name().is_some_and(|n| n == MAPS) {
        if let Some(run) = resolved.parent() {
            if let Some(r) = run_record(run) {
                if r["complete"] == json!(false) && r["stages"]["fit"].is_null() {
                    anyhow::bail!(
                        "unfinished maps {} (the `svbrdf run` writing them stopped before the fit finished; expected finished maps: run the same `svbrdf run ... --out {}` again to resume it)",
                        maps.display(),
                        run.display()
                    );
                }
            }
        }
    }
    Ok(())
}

/// Read a fit output folder: the exportable maps and the light intensity the fit used.
pub fn load_fit(dir: &Path) -> Result<(MaterialMaps, [f64; 3])> {
    let m = svbrdf_fit::output::read_maps(dir)
        .with_context(|| format!("reading the fitted maps in {}", dir.display()))?;
    let model = match m.manifest.model.as_str() {
        "ward" => ModelKind::Ward,
        "ggx" => ModelKind::Ggx,
        other => anyhow::bail!(
            "{}: unknown model {other:?} (expected ward or ggx)",
            dir.join("fit.json").display()
        ),
    };
    let maps = MaterialMaps {
        model,
        grid: m.grid,
        params: m.params,
        coverage: m.coverage,
        confidence: m.confidence,
    };
    Ok((maps, m.manifest.summary.light_intensity))
}

/// Read a fit output folder as exportable maps.
pub fn load_maps(dir: &Path) -> Result<MaterialMaps> {
    load_fit(dir).map(|(maps, _)| maps)
}

fn export_config(a: &ExportArgs) -> ExportConfig {
    ExportConfig {
        name: a.name.clone(),
        sphere: !a.no_sphere,
        mask_unobserved: a.mask_unobserved,
        ..ExportConfig::default()
    }
}

pub fn run_export(a: &ExportArgs) -> Result<svbrdf_export::ExportSummary> {
    let cfg = export_config(a);
    cfg.validate()?;
    for sub in ["gltf", "mitsuba"] {
        svbrdf_core::fsutil::check_output_spares_inputs(
            &a.out.join(sub),
            std::slice::from_ref(&a.maps),
        )?;
    }
    refuse_unfinished_maps(&a.maps)?;
    let maps = load_maps(&a.maps)?;
    let s = svbrdf_export::export_all(&maps, &cfg, &a.out, a.overwrite)?;
    say!("wrote {} (glTF 2.0)", s.gltf.display());
    say!(
        "wrote {} (Mitsuba 3; render with python3 {})",
        s.mitsuba.display(),
        s.mitsuba.with_file_name("render.py").display()
    );
    Ok(s)
}

#[derive(Args, Clone)]
#[command(allow_negative_numbers = true)]
pub struct RunArgs {
    /// The flash video (any container and codec FFmpeg decodes).
    #[arg(long, required_unless_present = "capture", requires = "reference")]
    pub video: Option<PathBuf>,
    /// The reference photo showing all four markers (JPEG/PNG).
    #[arg(long, required_unless_present = "capture", requires = "video")]
    pub reference: Option<PathBuf>,
    /// Instead of --video and --reference: a registered capture made elsewhere
    /// (`svbrdf import`, `svbrdf align --photos`, another tool); alignment is skipped.
    #[arg(long, conflicts_with_all = ["video", "reference", "second_video"])]
    pub capture: Option<PathBuf>,
    /// Phone description (JSON; see `svbrdf align --help`). Default: the paper's phone.
    #[arg(long)]
    pub camera: Option<PathBuf>,
    /// Output folder: aligned/, maps/, export/, report.html, run.json. Finished stages
    /// whose inputs and settings did not change are reused.
    #[arg(long)]
    pub out: PathBuf,
    /// Output region on the plane as x_min,x_max,y_min,y_max in cm (default: bounded
    /// by the markers' inner corners).
    #[arg(long, value_delimiter = ',', num_args = 1..=4, allow_hyphen_values = true)]
    pub region: Option<Vec<f64>>,
    /// Map resolution in pixels per cm (default: half the frames' sampling density).
    #[arg(long)]
    pub px_per_cm: Option<f64>,
    /// Reflectance model: `ward` (the paper's) or `ggx` (with Fresnel).
    #[arg(long, default_value = "ward")]
    pub model: String,
    /// Fit settings file (JSON subset of `svbrdf_fit::FitConfig`).
    #[arg(long)]
    pub fit_config: Option<PathBuf>,
    /// Skip the per-pixel refinement (maps constant within each cluster, as the paper).
    #[arg(long)]
    pub no_refine: bool,
    /// Read every observation as lit by the flash alone instead of estimating the
    /// room's light (see `fit --no-room-light`).
    #[arg(long)]
    pub no_room_light: bool,
    /// Take every flash frame as recorded at the same exposure (exposure locked)
    /// instead of estimating one gain per frame.
    #[arg(long)]
    pub fixed_exposure: bool,
    /// Seed of the clustering's random choices.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Folds of held-out frames that choose the fit's settings (default 3; 0 fits
    /// with the settings as given).
    #[arg(long, value_name = "K")]
    pub select_folds: Option<usize>,
    /// Rerun every stage even when its earlier result is still valid.
    #[arg(long)]
    pub force: bool,
    /// Allow replacing an output folder that holds a run of other inputs.
    #[arg(long)]
    pub overwrite: bool,
    #[command(flatten)]
    pub second: crate::SecondArgs,
    /// With --second-video: if the second video cannot be used (no flash onset, too
    /// long, not alignable), warn and fit the flash video alone instead of stopping.
    #[arg(long)]
    pub one_camera_fallback: bool,
    /// For simulated captures: the `svbrdf synth` folder whose ground truth the
    /// alignment and the maps are compared with (figures and pictures in truth/ and in
    /// the report).
    #[arg(long)]
    pub truth: Option<PathBuf>,
}

impl RunArgs {
    /// Defaults for a simulated capture folder (`svbrdf synth` output) at its map
    /// resolution, every stage rerun, compared with its truth: what `demo` and
    /// `bench --preset` run.
    pub fn for_synthetic_capture(capture: &Path, out: PathBuf, px_per_cm: f64) -> Self {
        Self {
            video: Some(capture.join("flash.mp4")),
            reference: Some(capture.join("reference.jpg")),
            capture: None,
            camera: Some(capture.join("camera.json")),
            out,
            region: None,
            px_per_cm: Some(px_per_cm),
            model: "ward".into(),
            fit_config: None,
            no_refine: false,
            no_room_light: false,
            fixed_exposure: false,
            seed: None,
            select_folds: None,
            force: true,
            overwrite: true,
            second: crate::SecondArgs::default(),
            one_camera_fallback: false,
            truth: Some(capture.to_path_buf()),
        }
    }
}

fn fnv1a(bytes: &[u8], mut h: u64) -> u64 {
    for b in bytes {
        h ^= u64::from(*b);
        h = h.wrapping_mul(0x100_0000_01b3);
    }
    h
}

/// A file's identity: absolute path, size, modification time and a hash of its first
/// megabyte (enough to notice a replaced file without reading a 1 GB video).
fn file_identity(p: &Path) -> Result<Value> {
    use std::io::Read;
    let meta = std::fs::metadata(p)
        .with_context(|| format!("invalid input {} (expected an existing file)", p.display()))?;
    anyhow::ensure!(
        meta.is_file(),
        "invalid input {} (expected a file, found a folder)",
        p.display()
    );
    let mtime = meta
        .modified()
        .ok()
        .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
        .map(|d| d.as_secs_f64());
    let mut head = Vec::new();
    std::fs::File::open(p)
        .with_context(|| format!("opening {}", p.display()))?
        .take(1 << 20)
        .read_to_end(&mut head)
        .with_context(|| format!("reading {}", p.display()))?;
    Ok(json!({
        "path": std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf()),
        "bytes": meta.len(),
        "modified": mtime,
        "head_fnv1a": format!("{:016x}", fnv1a(&head, 0xcbf2_9ce4_8422_2325)),
    }))
}

fn fingerprint(v: &Value) -> String {
    format!(
        "{:016x}",
        fnv1a(v.to_string().as_bytes(), 0xcbf2_9ce4_8422_2325)
    )
}

/// What `run` did.
pub struct RunOutcome {
    pub out: PathBuf,
    pub record: Value,
    /// With `--truth`: the alignment accuracy (JSON) and the map accuracy.
    pub truth: Option<(Value, svbrdf_fit::evaluate::Accuracy)>,
}

fn write_record(path: &Path, record: &Value) -> Result<()> {
    svbrdf_core::fsutil::write_json(path, record)?;
    Ok(())
}

/// Align, fit, export and report, reusing finished stages.
pub fn run_pipeline(a: &RunArgs) -> Result<RunOutcome> {
    let align_args = crate::AlignArgs {
        video: a.video.clone(),
        reference: a.reference.clone().unwrap_or_default(),
        photos: None,
        camera: a.camera.clone(),
        out: a.out.join(ALIGNED),
        region: a.region.clone(),
        px_per_cm: a.px_per_cm,
        fine_method: None,
        fine_long_side: None,
        overlap_weight: None,
        max_noise_gain: None,
        edge_noise_gain: None,
        fine_features: None,
        fine_min_inliers: None,
        fine_inlier_px: None,
        fine_recheck_px: None,
        fine_fill: None,
        subframes: None,
        all_pairs: false,
        fixed_exposure: a.fixed_exposure,
        no_self_check: false,
        max_pairs_per_frame: None,
        sharpest_within: None,
        marker_views: None,
        no_reference_matches: false,
        no_plane_ties: false,
        no_densify: false,
        no_marker_corners: false,
        no_relief: false,
        second: a.second.clone(),
        overwrite: true,
    };
    let fit_args = crate::fit_cmd::FitArgs {
        capture: a.capture.clone().unwrap_or_else(|| a.out.join(ALIGNED)),
        out: a.out.join(MAPS),
        options: crate::fit_cmd::FitOptions {
            config: a.fit_config.clone(),
            model: a.model.clone(),
            px_per_cm: None,
            light_intensity: None,
            no_refine: a.no_refine,
            no_room_light: a.no_room_light,
            seed: a.seed,
            select_folds: a.select_folds,
        },
        overwrite: true,
    };
    let export_args = ExportArgs {
        maps: a.out.join(MAPS),
        out: a.out.join(EXPORT),
        name: "svbrdf_material".into(),
        no_sphere: false,
        mask_unobserved: false,
        overwrite: true,
    };
    // Validate every setting before the first stage starts.
    let align_cfg = crate::align_config(&align_args)?;
    let fit_cfg = crate::fit_cmd::fit_config(&fit_args.options)?;
    let export_cfg = export_config(&export_args);
    export_cfg.validate()?;

    let identity = |p: &Option<PathBuf>| -> Result<Value> {
        p.as_ref().map_or(Ok(Value::Null), |p| file_identity(p))
    };
    let inputs = json!({
        "video": identity(&a.video)?,
        "reference": identity(&a.reference)?,
        "capture": identity(&a.capture.as_ref().map(|c| if c.is_dir() { c.join(svbrdf_core::capture::CAPTURE_FILE) } else { c.clone() }))?,
        "camera": match &a.camera { Some(c) => file_identity(c)?, None => Value::Null },
        "second_video": identity(&a.second.second_video)?,
        "second_camera": identity(&a.second.second_camera)?,
    });
    let record_path = a.out.join(RUN_FILE);
    let previous: Option<Value> = if record_path.exists() {
        let v: Value = svbrdf_core::fsutil::read_json(&record_path)?;
        (v["format"] == RUN_FORMAT).then_some(v)
    } else {
        None
    };
    if a.out.exists() && !a.overwrite {
        let non_empty = std::fs::read_dir(&a.out)
            .with_context(|| format!("reading {}", a.out.display()))?
            .next()
            .is_some();
        match &previous {
            None if non_empty => anyhow::bail!(
                "invalid output folder {} (it holds files that are not an svbrdf run; expected a new or empty folder, or pass --overwrite)",
                a.out.display()
            ),
            Some(p) if p["inputs"]["video"]["head_fnv1a"] != inputs["video"]["head_fnv1a"]
                || p["inputs"]["video"]["bytes"] != inputs["video"]["bytes"]
                || p["inputs"]["capture"]["head_fnv1a"] != inputs["capture"]["head_fnv1a"] =>
            {
                anyhow::bail!(
                    "invalid output folder {} (it holds a run of another input, {}; expected a new folder, or pass --overwrite)",
                    a.out.display(),
                    if p["inputs"]["video"].is_null() { &p["inputs"]["capture"]["path"] } else { &p["inputs"]["video"]["path"] }
                )
            }
            _ => {}
        }
    }
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;

    let settings = json!({
        "align": align_cfg,
        "fit": fit_cfg,
        "export": export_cfg,
    });
    let mut record = json!({
        "format": RUN_FORMAT,
        "version": 1,
        "svbrdf": env!("CARGO_PKG_VERSION"),
        "inputs": inputs,
        "settings": settings,
        "stages": {},
    });
    let old_stage = |name: &str| previous.as_ref().map(|p| p["stages"][name].clone());
    // Each stage's fingerprint (chained over the stages before it) and whether its
    // earlier result can be reused, decided before anything changes on disk.
    let mut plan: Vec<(String, bool)> = Vec::new();
    let mut chain = fingerprint(&json!([record["svbrdf"], record["inputs"]]));
    for (name, dir) in [
        ("align", &align_args.out),
        ("fit", &fit_args.out),
        ("export", &export_args.out),
    ] {
        let fp = fingerprint(&json!([chain, record["settings"][name]]));
        let reusable = !a.force
            && dir.exists()
            && old_stage(name).is_some_and(|s| s["fingerprint"] == json!(fp));
        // Before the first stage changes anything, the record keeps only the stages
        // that stay valid (and says below that the folder is unfinished).
        if reusable {
            record["stages"][name] = old_stage(name).unwrap_or(Value::Null);
        }
        plan.push((fp.clone(), reusable));
        chain = fp;
    }
    // An interruption from here on leaves a folder that `view`, `export` and the report
    // refuse until `run` resumes it. The old report (of the old maps) goes at once.
    record["complete"] = json!(false);
    for d in [&align_args.out, &fit_args.out, &export_args.out] {
        svbrdf_core::fsutil::remove_stale_siblings(d);
    }
    write_record(&record_path, &record)?;
    let old_report = a.out.join("report.html");
    if old_report.exists() {
        std::fs::remove_file(&old_report)
            .with_context(|| format!("removing the old {}", old_report.display()))?;
    }
    type Stage<'a> = (&'a str, &'a Path, Box<dyn Fn() -> Result<()> + 'a>);
    let stages: Vec<Stage> = vec![
        (
            "align",
            &align_args.out,
            Box::new(|| match crate::run_align(&align_args) {
                Err(e)
                    if a.one_camera_fallback
                        && matches!(
                            e.downcast_ref::<svbrdf_align::AlignError>(),
                            Some(svbrdf_align::AlignError::SecondStream(_))
                        ) =>
                {
                    say!("warning: {e}");
                    say!("warning: --one-camera-fallback: aligning the flash video alone");
                    let mut one = align_args.clone();
                    one.second = crate::SecondArgs::default();
                    crate::run_align(&one)
                }
                r => r,
            }),
        ),
        (
            "fit",
            &fit_args.out,
            Box::new(|| crate::fit_cmd::run_fit(&fit_args).map(|_| ())),
        ),
        (
            "export",
            &export_args.out,
            Box::new(|| run_export(&export_args).map(|_| ())),
        ),
    ];
    for ((name, dir, stage), (fp, reusable)) in stages.iter().zip(&plan) {
        if *name == "align" && a.capture.is_some() {
            say!(
                "== align: skipped (registered capture given: {})",
                fit_args.capture.display()
            );
            continue;
        }
        if *reusable {
            say!(
                "== {name}: reusing {} (inputs and settings unchanged)",
                dir.display()
            );
        } else {
            say!("== {name}");
            crate::bench::reset_peak_memory();
            let t0 = Instant::now();
            stage()?;
            record["stages"][*name] = json!({
                "fingerprint": fp,
                "seconds": t0.elapsed().as_secs_f64(),
                "peak_memory_mb": crate::bench::peak_memory_kb().map(|k| k as f64 / 1024.0),
                "output": dir.file_name().map(|f| f.to_string_lossy().into_owned()),
            });
            // Record each finished stage at once, so an interrupted run resumes here.
            write_record(&record_path, &record)?;
        }
        say!();
    }
    // Every stage's doubts in one list.
    let mut warnings = Vec::new();
    for (file, key) in [
        (a.out.join(ALIGNED).join("align.json"), "summary"),
        (a.out.join(MAPS).join("fit.json"), "summary"),
    ] {
        if let Ok(v) = svbrdf_core::fsutil::read_json::<Value>(&file) {
            if let Some(w) = v[key]["warnings"].as_array() {
                warnings.extend(w.iter().filter_map(|s| s.as_str().map(String::from)));
            }
        }
    }
    record["warnings"] = json!(warnings);
    write_record(&record_path, &record)?;
    let (maps, light_intensity) = load_fit(&a.out.join(MAPS))?;
    let truth = match &a.truth {
        Some(capture) => {
            let t0 = Instant::now();
            let t = crate::bench::truth_section(&a.out, capture, &maps, light_intensity)?;
            record["truth_seconds"] = json!(t0.elapsed().as_secs_f64());
            Some(t)
        }
        None => None,
    };
    say!("== report");
    let t0 = Instant::now();
    let report = svbrdf_export::report::write_report(&a.out, Some(&maps))?;
    record["report_seconds"] = json!(t0.elapsed().as_secs_f64());
    record["complete"] = json!(true);
    write_record(&record_path, &record)?;
    say!("wrote {}", report.display());
    say!();
    Ok(RunOutcome {
        out: a.out.clone(),
        record,
        truth,
    })
}

/// The closing summary of a run.
pub fn print_run_summary(o: &RunOutcome) -> Result<()> {
    let align: Value = svbrdf_core::fsutil::read_json(&o.out.join(ALIGNED).join("align.json"))
        .unwrap_or(Value::Null);
    let fit: Value = svbrdf_core::fsutil::read_json(&o.out.join(MAPS).join("fit.json"))?;
    say!("== summary");
    if let Ok(f) =
        serde_json::from_value::<svbrdf_align::DropCounts>(align["summary"]["frames"].clone())
    {
        say!("frames: {}", f.describe());
    }
    if let Ok(second) = serde_json::from_value::<svbrdf_align::SecondStreamSummary>(
        align["summary"]["second"].clone(),
    ) {
        say!("second video: {}", second.describe());
    }
    let s = &fit["summary"];
    say!(
        "clusters: {} initial, {} final; model {}",
        s["initial_clusters"],
        s["final_clusters"],
        fit["model"].as_str().unwrap_or("?")
    );
    let secs: Vec<String> = ["align", "fit", "export"]
        .iter()
        .map(|n| {
            format!(
                "{n} {:.1} s",
                o.record["stages"][*n]["seconds"].as_f64().unwrap_or(0.0)
            )
        })
        .collect();
    say!("stage times (when last run): {}", secs.join(", "));
    say!("files:");
    for (what, p) in [
        ("report", o.out.join("report.html")),
        (
            "glTF",
            o.out.join(EXPORT).join("gltf").join("material.gltf"),
        ),
        (
            "Mitsuba",
            o.out.join(EXPORT).join("mitsuba").join("scene.xml"),
        ),
        ("maps", o.out.join(MAPS).join("maps")),
        (
            "registered capture",
            o.out.join(ALIGNED).join("capture.json"),
        ),
    ] {
        if p.exists() {
            say!("  {what:>18}: {}", p.display());
        }
    }
    Ok(())
}

#[derive(Args, Clone)]
#[command(allow_negative_numbers = true)]
pub struct MarkersArgs {
    /// Output folder: markers.svg (print this at 100%) and markers.png (300 dpi).
    #[arg(long)]
    pub out: PathBuf,
    /// Marker dictionary, as OpenCV names it (e.g. DICT_6X6_250, DICT_APRILTAG_36h11).
    #[arg(long, default_value = "DICT_6X6_250")]
    pub dictionary: String,
    /// Printed side of each marker in cm, black border included (paper: 1.6). Put the
    /// same number in camera.json as marker_size_cm.
    #[arg(long, default_value_t = 1.6)]
    pub size_cm: f64,
    /// Replace the output folder if it exists.
    #[arg(long)]
    pub overwrite: bool,
}

pub fn run_markers(a: &MarkersArgs) -> Result<()> {
    use svbrdf_export::markers::{raster, svg, MarkerCells};
    let dict = svbrdf_cv::aruco::Dictionary::from_name(&a.dictionary)?;
    let size_mm = a.size_cm * 10.0;
    let cells: Vec<MarkerCells> = (0..4)
        .map(|id| {
            svbrdf_cv::aruco::marker_pattern(dict, id).map(|p| MarkerCells {
                id,
                cells: p.cells,
                white: p.white,
            })
        })
        .collect::<Result<_, _>>()?;
    let svg_text = svg(&cells, size_mm, dict.name())?;
    let img = raster(&cells, size_mm)?;
    let staging = svbrdf_core::fsutil::StagingDir::new(&a.out, a.overwrite, &[])?;
    let dir = staging.path();
    std::fs::write(dir.join("markers.svg"), svg_text)
        .with_context(|| format!("writing {}", dir.join("markers.svg").display()))?;
    let png_path = dir.join("markers.png");
    let file = std::fs::File::create(&png_path)
        .with_context(|| format!("writing {}", png_path.display()))?;
    let mut enc = png::Encoder::new(
        std::io::BufWriter::new(file),
        img.width as u32,
        img.height as u32,
    );
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::Eight);
    // 300 dots per inch, so that printing "actual size" keeps the physical scale.
    let ppm = (svbrdf_export::markers::DPI / 0.0254).round() as u32;
    enc.set_pixel_dims(Some(png::PixelDimensions {
        xppu: ppm,
        yppu: ppm,
        unit: png::Unit::Meter,
    }));
    let mut w = enc.write_header()?;
    w.write_image_data(&img.data)?;
    w.finish()?;
    let out = staging.commit()?;
    say!(
        "wrote {0}/markers.svg and {0}/markers.png (300 dpi): ids 0-3 of {1}, {2} cm",
        out.display(),
        dict.name(),
        a.size_cm
    );
    say!("print at 100% (\"actual size\") and check that the scale bar measures 5 cm");
    Ok(())
}
