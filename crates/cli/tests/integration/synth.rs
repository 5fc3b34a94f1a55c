//! `svbrdf synth --preset tiny`: decodable video, detectable markers, complete ground
//! truth, and pixels that the core BRDF model re-renders.

use std::path::Path;
use std::process::Command;

use svbrdf_core::brdf::{BrdfModel, BrdfParams, Ggx, LightView, ModelKind, Prepared, Ward};
use svbrdf_core::capture::RegisteredCapture;
use svbrdf_core::color::{linear_to_srgb8, srgb_to_linear};
use svbrdf_core::geometry::{mat3_from_rows, Camera, Pose, Vec2, Vec3};
use svbrdf_core::image::ImageF32;
use svbrdf_core::maps::{read_image_linear, Encoding};
use svbrdf_core::plane::PlaneGrid;
use svbrdf_cv::aruco::{detect_markers, Dictionary};
use svbrdf_cv::video::VideoReader;
use svbrdf_synth::truth::{CameraTruth, GroundTruth};

use crate::util::{svbrdf, temp_dir, tiny_capture};

fn truth(dir: &Path) -> GroundTruth {
    let text = std::fs::read_to_string(dir.join("ground_truth/truth.json")).unwrap();
    serde_json::from_str(&text).unwrap()
}

fn camera(c: &CameraTruth) -> Camera {
    Camera {
        intrinsics: c.intrinsics,
        distortion: c.distortion,
        pose: Pose {
            rotation: mat3_from_rows(&c.rotation),
            centre: Vec3::from(c.position),
        },
    }
}

#[test]
fn video_decodes_with_stated_frame_count_and_size() {
    let dir = tiny_capture();
    let t = truth(dir);
    let stream = &t.streams[0];
    let expected = (t.config.video.fps * t.config.video.duration_s).round() as u64;
    assert_eq!(stream.frames.len() as u64, expected);

    // ffprobe, counting decoded frames rather than trusting the header.
    let o = Command::new("ffprobe")
        .args([
            "-v",
            "error",
            "-count_frames",
            "-select_streams",
            "v:0",
            "-show_entries",
        ])
        .args([
            "stream=codec_name,width,height,nb_read_frames",
            "-of",
            "csv=p=0",
        ])
        .arg(dir.join("flash.mp4"))
        .output()
        .expect("ffprobe must be installed (the setup script installs ffmpeg)");
    assert!(o.status.success());
    let line = String::from_utf8_lossy(&o.stdout).trim().to_string();
    assert_eq!(
        line,
        format!("h264,{},{},{}", stream.width, stream.height, expected)
    );

    // OpenCV, streaming.
    let mut r = VideoReader::open(&dir.join("flash.mp4")).unwrap();
    let info = r.info();
    assert_eq!((info.width, info.height), (stream.width, stream.height));
    assert!((info.fps - stream.fps).abs() < 1e-6);
    let mut n = 0;
    while let Some(f) = r.read().unwrap() {
        assert_eq!(
            (f.width as u32, f.height as u32),
            (stream.width, stream.height)
        );
        n += 1;
    }
    assert_eq!(n, expected);
}

#[test]
fn reference_markers_detected_within_one_pixel() {
    let dir = tiny_capture();
    let t = truth(dir);
    let img = svbrdf_cv::read_image(&dir.join(&t.reference.file)).unwrap();
    let found = detect_markers(
        &img,
        Dictionary::from_name(&t.config.markers.dictionary).unwrap(),
    )
    .unwrap();
    assert_eq!(
        found.iter().map(|m| m.id).collect::<Vec<_>>(),
        t.config.markers.ids.to_vec()
    );
    let mut worst: f64 = 0.0;
    for (id, corners) in &t.reference.marker_corners_px {
        let m = found.iter().find(|m| m.id == *id).unwrap();
        for k in 0..4 {
            let d = Vec2::new(
                m.corners[k][0] - corners[k][0],
                m.corners[k][1] - corners[k][1],
            )
            .norm();
            worst = worst.max(d);
        }
    }
    assert!(worst < 1.0, "worst corner error {worst} px");
    // The truth's projection agrees with its world corners.
    let cam = camera(&t.reference.camera);
    for m in &t.markers {
        let px = &t
            .reference
            .marker_corners_px
            .iter()
            .find(|(i, _)| *i == m.id)
            .unwrap()
            .1;
        for k in 0..4 {
            let p = cam.project(Vec3::from(m.corners_cm[k])).unwrap();
            assert!((p - Vec2::new(px[k][0], px[k][1])).norm() < 1e-9);
        }
    }
}

#[test]
fn ground_truth_files_are_complete() {
    let dir = tiny_capture();
    let t = truth(dir);
    let grid = PlaneGrid::new(t.region, t.maps.px_per_cm).unwrap();
    let gt = dir.join("ground_truth");
    for f in [
        &t.maps.diffuse,
        &t.maps.specular,
        &t.maps.roughness,
        &t.maps.normal,
        &t.maps.mask,
    ] {
        let img = read_image_linear(&gt.join(f), Encoding::Linear).unwrap();
        assert_eq!((img.width, img.height), (grid.width, grid.height), "{f}");
        assert!(img.data.iter().all(|v| v.is_finite()), "{f}");
    }
    assert_eq!(t.holdout.len(), t.config.holdout_lights_cm.len());
    for h in &t.holdout {
        let img = read_image_linear(&gt.join(&h.exr), Encoding::Linear).unwrap();
        assert!(img.data.iter().any(|v| *v > 0.01));
        assert!(gt.join(&h.png).is_file());
    }
    assert!(dir.join("camera.json").is_file());
    let cap = RegisteredCapture::load(&dir.join("registered")).unwrap();
    let step = t.config.frame_step as usize;
    // Every step-th frame but those rendered with motion blur (which alignment drops).
    let sharp = t.streams[0]
        .frames
        .iter()
        .step_by(step)
        .filter(|f| !f.motion_blur)
        .count();
    assert_eq!(cap.frames.len(), sharp);
    assert!(cap
        .frames
        .iter()
        .all(|f| !t.streams[0].frames[f.frame_index.unwrap() as usize].motion_blur));
    assert_eq!(cap.region, t.region);
    // Markers are visible in some frames but not all is the paper's setting; tiny is
    // small enough that most frames see one, so only check that visibility is recorded.
    assert!(t.streams[0]
        .frames
        .iter()
        .any(|f| !f.markers_visible.is_empty()));
}

fn sample(img: &ImageF32, grid: &PlaneGrid, p: Vec2) -> [f64; 3] {
    let q = grid.to_pixel(p);
    let mut o = [0f32; 3];
    img.sample_bilinear(q.x, q.y, &mut o);
    o.map(f64::from)
}

/// Differences between a capture's video pixels and the truth maps rendered with
/// `model` (sRGB code values, sorted) and the mean linear bias, over every 9th sharp
/// frame; clipped values are left out.
fn re_render_errors(dir: &Path, model: &dyn BrdfModel) -> (Vec<f64>, f64) {
    let t = truth(dir);
    let gt = dir.join("ground_truth");
    let load = |f: &str| read_image_linear(&gt.join(f), Encoding::Linear).unwrap();
    let (diffuse, specular, rough, normal, mask) = (
        load(&t.maps.diffuse),
        load(&t.maps.specular),
        load(&t.maps.roughness),
        load(&t.maps.normal),
        load(&t.maps.mask),
    );
    let grid = PlaneGrid::new(t.region, t.maps.px_per_cm).unwrap();
    let inner = t.region.expanded(-0.2);
    let stream = &t.streams[0];
    let wanted: Vec<u64> = stream
        .frames
        .iter()
        .filter(|f| !f.motion_blur)
        .map(|f| f.index)
        .step_by(9)
        .collect();
    let mut reader = VideoReader::open(&dir.join(&stream.file)).unwrap();
    let mut errors = Vec::new();
    let mut signed = 0.0;
    while let Some(frame) = reader.read().unwrap() {
        let idx = reader.next_index() - 1;
        if !wanted.contains(&idx) {
            continue;
        }
        let ft = &stream.frames[idx as usize];
        let cam = camera(&ft.camera);
        let light = Vec3::from(ft.light_position.unwrap());
        for y in (4..frame.height - 4).step_by(5) {
            for x in (4..frame.width - 4).step_by(5) {
                let Some(p) = cam.pixel_to_plane(Vec2::new(x as f64, y as f64)) else {
                    continue;
                };
                if !inner.contains(p) || sample(&mask, &grid, p)[0] < 1.0 {
                    continue;
                }
                let a = sample(&rough, &grid, p);
                let n = sample(&normal, &grid, p);
                let params = BrdfParams {
                    rho_d: sample(&diffuse, &grid, p),
                    rho_s: sample(&specular, &grid, p),
                    alpha_x: a[0],
                    alpha_y: a[1],
                    ..BrdfParams::default()
                };
                let prep = Prepared::from_normal(params, Vec3::new(n[0], n[1], n[2]).normalize());
                let obs = LightView::from_points(Vec3::new(p.x, p.y, 0.0), light, cam.pose.centre);
                let l = model.radiance(&prep, &obs, t.light_intensity);
                for c in 0..3 {
                    let lin = l[c] + t.ambient * params.rho_d[c];
                    if lin > 0.95 {
                        continue; // clipped highlights carry no information
                    }
                    let expect = f64::from(linear_to_srgb8(lin));
                    let got = f64::from(frame.pixel(x, y)[c]);
                    errors.push((got - expect).abs());
                    signed += srgb_to_linear(got / 255.0) - lin;
                }
            }
        }
    }
    assert!(errors.len() > 2000, "only {} samples", errors.len());
    errors.sort_by(f64::total_cmp);
    let bias = signed / errors.len() as f64;
    (errors, bias)
}

fn quantile(sorted: &[f64], f: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * f) as usize]
}

/// Noise (a few code values) plus H.264 smoothing of texture edges.
fn assert_re_renders(errors: &[f64], bias: f64) {
    let q = |f| quantile(errors, f);
    eprintln!(
        "re-render: n={} median={} p90={} bias={bias:.5}",
        errors.len(),
        q(0.5),
        q(0.9)
    );
    assert!(q(0.5) <= 4.0, "median error {} code values", q(0.5));
    assert!(
        q(0.9) <= 12.0,
        "90th percentile error {} code values",
        q(0.9)
    );
    assert!(bias.abs() < 0.01, "mean linear bias {bias}");
}

#[test]
fn core_model_re_renders_video_pixels() {
    let (errors, bias) = re_render_errors(tiny_capture(), &Ward);
    assert_re_renders(&errors, bias);
}

/// `synth --brdf ggx` renders the material with GGX everywhere: the video, and the
/// held-out images, which the truth's maps reproduce through GGX and not through Ward.
#[test]
fn ggx_rendered_capture_is_reproduced_by_ggx_not_ward() {
    let dir = temp_dir().join("synth-ggx");
    let o = svbrdf(&[
        "synth",
        "--preset",
        "tiny",
        "--material",
        "brushed-metal",
        "--brdf",
        "ggx",
        "--duration",
        "1.5",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", crate::util::stderr(&o));
    assert_eq!(truth(&dir).config.brdf, ModelKind::Ggx);
    let (errors, bias) = re_render_errors(&dir, &Ggx);
    assert_re_renders(&errors, bias);
    let (ward, _) = re_render_errors(&dir, &Ward);
    let mean = |e: &[f64]| e.iter().sum::<f64>() / e.len() as f64;
    eprintln!("mean error: ggx {} ward {}", mean(&errors), mean(&ward));
    assert!(
        mean(&ward) > 1.3 * mean(&errors) && quantile(&ward, 0.99) > quantile(&errors, 0.99) + 5.0,
        "Ward reproduces the GGX capture as well as GGX: {} vs {}",
        mean(&ward),
        mean(&errors)
    );
    // The held-out images: the true maps relit with the truth's model (GGX) match them
    // exactly (floor at blur 0), so accuracy figures compare against GGX images.
    let o = svbrdf(&[
        "bench",
        "--no-brdf",
        "--truth",
        dir.to_str().unwrap(),
        "--truth-blur",
        "0",
    ]);
    assert!(o.status.success(), "{}", crate::util::stderr(&o));
    let floor = &crate::util::json_lines(&o)[0]["accuracy"]["relight_relative_rmse"];
    for v in floor.as_array().unwrap() {
        assert!(v.as_f64().unwrap() < 1e-4, "relit truth differs: {floor}");
    }
}

#[test]
fn output_is_deterministic_for_a_seed() {
    let root = temp_dir();
    let run = |name: &str, seed: &str| {
        let out = root.join(name);
        let o = svbrdf(&[
            "synth",
            "--seed",
            seed,
            "--duration",
            "0.3",
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        out
    };
    let (a, b, c) = (run("a", "5"), run("b", "5"), run("c", "6"));
    for f in [
        "ground_truth/truth.json",
        "reference.jpg",
        "ground_truth/maps/diffuse.png",
        "flash.mp4",
    ] {
        assert_eq!(
            std::fs::read(a.join(f)).unwrap(),
            std::fs::read(b.join(f)).unwrap(),
            "{f} differs"
        );
    }
    // EXR attribute order follows a hash map, so compare EXR content, not bytes.
    for f in [
        "ground_truth/maps/normal.exr",
        "ground_truth/holdout/light_00.exr",
    ] {
        let (x, y) = (
            read_image_linear(&a.join(f), Encoding::Linear).unwrap(),
            read_image_linear(&b.join(f), Encoding::Linear).unwrap(),
        );
        assert_eq!(x, y, "{f} differs");
    }
    assert_ne!(
        std::fs::read(a.join("reference.jpg")).unwrap(),
        std::fs::read(c.join("reference.jpg")).unwrap()
    );
}

#[test]
fn demo_runs_the_whole_pipeline() {
    let out = temp_dir().join("demo");
    let o = svbrdf(&["demo", "--out", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout);
    for needle in [
        "flash.mp4",
        "alignment error: median",
        "diffuse albedo RMSE",
        "relighting under",
        "report.html",
    ] {
        assert!(text.contains(needle), "{needle} missing:\n{text}");
    }
    for f in [
        "capture/registered/capture.json",
        "run/aligned/capture.json",
        "run/aligned/panorama.png",
        "run/maps/fit.json",
        "run/export/gltf/material.gltf",
        "run/export/mitsuba/scene.xml",
        "run/truth/accuracy.json",
        "run/report.html",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
}

#[test]
fn second_camera_starts_early_and_sees_the_flash_onset() {
    let out = temp_dir().join("two");
    let o = svbrdf(&[
        "synth",
        "--second-camera",
        "--duration",
        "1",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let t = truth(&out);
    assert_eq!(t.streams.len(), 2);
    let s = &t.streams[1];
    let sc = t.config.second_camera.as_ref().unwrap();
    assert!(!s.flash && (s.start_time_s + sc.lead_s).abs() < 1e-12);
    // The onset frame is the first whose readout reaches t = 0 on the flash clock.
    let onset = s.flash_onset_frame.unwrap() as usize;
    let expected = ((sc.lead_s - sc.readout_s) * sc.fps).ceil() as usize;
    assert_eq!(onset, expected);
    assert!(s.frames[..onset].iter().all(|f| f.light_position.is_none()));
    assert!(
        s.frames[onset].first_lit_row.unwrap() > 0,
        "rolling-shutter onset should split the frame"
    );
    // It stops before the flash camera does (the paper's requirement).
    let last = s.frames.last().unwrap().time_s;
    assert!(last < t.config.video.duration_s);
    // Decoded brightness jumps at the onset.
    let mut r = VideoReader::open(&out.join(&s.file)).unwrap();
    let mut means = Vec::new();
    while let Some(f) = r.read().unwrap() {
        means.push(f.data.iter().map(|v| f64::from(*v)).sum::<f64>() / f.data.len() as f64);
    }
    assert_eq!(means.len(), s.frames.len());
    assert!(
        means[onset + 1] > means[onset - 1] + 20.0,
        "{:?}",
        &means[onset - 2..onset + 2]
    );
    // Only lit frames enter the registered capture.
    let cap = RegisteredCapture::load(&out.join("registered")).unwrap();
    assert!(cap.frames.iter().any(|f| f.source == 1));
    assert!(cap
        .frames
        .iter()
        .filter(|f| f.source == 1)
        .all(|f| f.frame_index.unwrap() >= onset as u64));
}

#[test]
fn material_from_map_images() {
    use svbrdf_core::maps::{write_png, PngDepth};
    let maps = temp_dir();
    let (w, h) = (32, 32);
    let mut diffuse = ImageF32::new(w, h, 3);
    for (i, v) in diffuse.data.iter_mut().enumerate() {
        *v = 0.1 + 0.6 * ((i / 3) % w) as f32 / w as f32;
    }
    write_png(
        &maps.join("diffuse.png"),
        &diffuse,
        Encoding::Srgb,
        PngDepth::Sixteen,
        &[],
    )
    .unwrap();
    let mut rough = ImageF32::new(w, h, 3);
    rough.data.iter_mut().for_each(|v| *v = 0.2);
    write_png(
        &maps.join("roughness.png"),
        &rough,
        Encoding::Linear,
        PngDepth::Sixteen,
        &[],
    )
    .unwrap();
    let out = temp_dir().join("maps");
    let o = svbrdf(&[
        "synth",
        "--maps",
        maps.to_str().unwrap(),
        "--duration",
        "0.2",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let t = truth(&out);
    let gt = out.join("ground_truth");
    let d = read_image_linear(&gt.join(&t.maps.diffuse), Encoding::Linear).unwrap();
    // The map is stretched over the region: left edge dark, right edge bright, in linear.
    let row = d.height / 2;
    assert!(
        (f64::from(d.pixel(0, row)[0]) - 0.1).abs() < 0.02,
        "{}",
        d.pixel(0, row)[0]
    );
    assert!(
        (f64::from(d.pixel(d.width - 1, row)[0]) - 0.68).abs() < 0.03,
        "{}",
        d.pixel(d.width - 1, row)[0]
    );
    let r = read_image_linear(&gt.join(&t.maps.roughness), Encoding::Linear).unwrap();
    assert!(r
        .data
        .chunks(3)
        .all(|p| (p[0] - 0.2).abs() < 1e-3 && (p[1] - 0.2).abs() < 1e-3));
}
