//! `svbrdf align` on the tiny simulated capture: accuracy against ground truth (looser
//! bounds than the paper preset's benchmark targets), outputs, and bad input.

use std::path::Path;

use svbrdf_core::capture::{FrameMapping, RegisteredCapture};

use crate::util::{hard_small, read_json, stderr, svbrdf, temp_dir, tiny_capture};

pub(crate) fn align(cap: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    crate::util::align_synth(cap, out, extra)
}

/// A tiny capture of brushed metal (seed 1) rendered with `brdf`, in a new folder.
pub(crate) fn tiny_brushed_metal(name: &str, brdf: &str) -> std::path::PathBuf {
    let cap = temp_dir().join(name);
    let o = svbrdf(&[
        "synth",
        "--preset",
        "tiny",
        "--material",
        "brushed-metal",
        "--brdf",
        brdf,
        "--seed",
        "1",
        "--out",
        cap.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    cap
}

/// `svbrdf bench --align-capture OUT --truth CAP`: the alignment's accuracy.
pub(crate) fn alignment_accuracy(out: &Path, cap: &Path) -> serde_json::Value {
    let o = svbrdf(&[
        "bench",
        "--no-brdf",
        "--align-capture",
        out.to_str().unwrap(),
        "--truth",
        cap.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value =
        serde_json::from_str(String::from_utf8_lossy(&o.stdout).trim()).unwrap();
    eprintln!("{v}");
    v
}

#[test]
fn tiny_alignment_matches_ground_truth() {
    let cap = tiny_capture();
    let out = temp_dir().join("aligned");
    let o = align(cap, &out, &["--px-per-cm", "24"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("kept") && text.contains("timings"), "{text}");
    for f in [
        "capture.json",
        "panorama.png",
        "trajectory.png",
        "connectivity.png",
        "align.json",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let capture = RegisteredCapture::load(&out).unwrap();
    assert!(
        capture.frames.len() >= 12,
        "only {} frames kept",
        capture.frames.len()
    );
    // 3 x 5 sub-frames per frame; those that no correspondence of their own fixes are
    // left out (at the tiny size, mostly over the paper around the material), and a
    // frame keeps at least 30% of them.
    let counts: Vec<usize> = capture
        .frames
        .iter()
        .map(|f| match &f.mapping {
            FrameMapping::Homographies { subframes } => subframes.len(),
            FrameMapping::Pinhole { .. } => 0,
        })
        .collect();
    assert!(counts.iter().all(|&c| (5..=15).contains(&c)), "{counts:?}");
    assert!(
        counts.iter().sum::<usize>() * 10 >= counts.len() * 15 * 8,
        "{counts:?}"
    );

    let v = alignment_accuracy(out.as_path(), cap);
    let get = |k: &str| v[k].as_f64().unwrap();
    // Paper-preset targets are 0.25 / 0.5 px and 2 mm; tiny frames are 8x smaller.
    assert!(get("align_error_px_median") < 0.5, "{v}");
    assert!(get("align_error_px_p95") < 1.5, "{v}");
    assert!(get("camera_error_mm_median") < 3.0, "{v}");
    // The worst frame's p95 is one of the per-frame figures and bounds them all.
    let per_frame = v["per_frame_px_median_p95"].as_array().unwrap();
    let worst = get("worst_frame_px_p95");
    assert!(per_frame.iter().all(|f| f[2].as_f64().unwrap() <= worst));
    assert!(per_frame
        .iter()
        .any(|f| f[0] == v["worst_frame"] && f[2] == v["worst_frame_px_p95"]));
    assert!(worst < 3.0, "{v}");
}

#[test]
fn reference_without_markers_names_found_ids() {
    let cap = tiny_capture();
    let root = temp_dir();
    // A crop-free photo with no markers: a video frame's worth of material only.
    let img = svbrdf_cv::read_image(&cap.join("ground_truth/maps/diffuse.png")).unwrap();
    svbrdf_cv::write_jpeg(&root.join("plain.jpg"), &img, 90).unwrap();
    let out = root.join("out");
    let o = svbrdf(&[
        "align",
        "--video",
        cap.join("flash.mp4").to_str().unwrap(),
        "--reference",
        root.join("plain.jpg").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert_eq!(e.trim().lines().count(), 1, "{e}");
    assert!(
        e.contains("4 distinct markers") && e.contains("found ids []"),
        "{e}"
    );
    assert!(!out.exists());
}

#[test]
fn wrong_dictionary_and_unreadable_video() {
    let cap = tiny_capture();
    let root = temp_dir();
    std::fs::write(
        root.join("camera.json"),
        r#"{"marker_dictionary": "DICT_4X4_50"}"#,
    )
    .unwrap();
    let out = root.join("out");
    let o = svbrdf(&[
        "align",
        "--video",
        cap.join("flash.mp4").to_str().unwrap(),
        "--reference",
        cap.join("reference.jpg").to_str().unwrap(),
        "--camera",
        root.join("camera.json").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(e.contains("DICT_4X4_50") && e.contains("found ids"), "{e}");

    std::fs::write(
        root.join("camera.json"),
        r#"{"marker_dictionary": "DICT_9X9_1"}"#,
    )
    .unwrap();
    let o = svbrdf(&[
        "align",
        "--video",
        "x.mp4",
        "--reference",
        "y.jpg",
        "--camera",
        root.join("camera.json").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(
        stderr(&o).contains("DICT_9X9_1") && stderr(&o).contains("DICT_6X6_250"),
        "{}",
        stderr(&o)
    );

    std::fs::write(root.join("empty.mp4"), b"").unwrap();
    let o = svbrdf(&[
        "align",
        "--video",
        root.join("empty.mp4").to_str().unwrap(),
        "--reference",
        cap.join("reference.jpg").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert_eq!(e.trim().lines().count(), 1, "{e}");
    assert!(e.contains("empty.mp4"), "{e}");
    assert!(!out.exists());
}

#[test]
fn rotation_metadata_gives_upright_frames() {
    let cap = tiny_capture();
    let root = temp_dir();
    let rotated = root.join("rot.mp4");
    let st = std::process::Command::new("ffmpeg")
        .args(["-v", "error", "-y", "-i"])
        .arg(cap.join("flash.mp4"))
        .args(["-c", "copy", "-metadata:s:v:0", "rotate=90"])
        .arg(&rotated)
        .status()
        .expect("ffmpeg must be installed (the setup script installs it)");
    assert!(st.success());
    let mut a = svbrdf_cv::video::VideoReader::open(&cap.join("flash.mp4")).unwrap();
    let mut b = svbrdf_cv::video::VideoReader::open(&rotated).unwrap();
    let (ia, ib) = (a.info(), b.info());
    assert_eq!(
        (ib.width, ib.height),
        (ia.height, ia.width),
        "rotation metadata not applied to the reported size"
    );
    let (fa, fb) = (a.read().unwrap().unwrap(), b.read().unwrap().unwrap());
    assert_eq!((fb.width, fb.height), (fa.height, fa.width));
    // Same pixels, turned by a quarter either way.
    let (cw, ccw) = crate::util::quarter_turns(&fa, &fb);
    assert!(
        cw || ccw,
        "rotated frame does not match the original turned by 90 degrees"
    );
}

#[test]
fn alignment_is_reproducible_byte_for_byte() {
    // Frames are matched in parallel; the result must not depend on which thread ran
    // which pair (FLANN's random trees used to).
    let cap = tiny_capture();
    let outs: Vec<_> = (0..2)
        .map(|k| {
            let out = temp_dir().join(format!("repro{k}"));
            let o = align(cap, &out, &["--px-per-cm", "24"]);
            assert!(o.status.success(), "{}", stderr(&o));
            std::fs::read(out.join("capture.json")).unwrap()
        })
        .collect();
    assert!(
        outs[0] == outs[1],
        "two alignments of the same video differ"
    );
}

/// The `hard-small` preset (glazed tiles, markers fully in view in about 12% of the
/// frames, a rolled and tilted no-flash reference photo, k1 drawn per capture): the
/// registration is accurate in the markers' world frame, every frame passes the
/// self-check, and align.json records the reference camera, coverage and self-check.
#[test]
fn hard_small_tiles_align_within_the_issue_18_bounds() {
    let cap = temp_dir().join("hard");
    let o = svbrdf(&[
        "synth",
        "--preset",
        "hard-small",
        "--seed",
        "2",
        "--out",
        cap.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = temp_dir().join("aligned");
    let o = align(&cap, &out, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let rec: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("align.json")).unwrap()).unwrap();
    assert_eq!(rec["format"], "svbrdf-align");
    assert_eq!(rec["version"], 1);
    assert_eq!(rec["reference_camera"]["axes"], "markers");
    assert_eq!(
        rec["reference_camera"]["marker_corners_cm"]
            .as_array()
            .unwrap()
            .len(),
        4
    );
    let s = &rec["summary"];
    assert!(s["coverage"].as_f64().unwrap() > 0.9, "{s}");
    // At least 90% of the sharp sampled frames registered (issue 18). This capture's
    // chain of frames breaks twice on the tiles: the pieces after the breaks are kept
    // because the reference photo ties them to the plane.
    let f = &s["frames"];
    let sharp = f["decoded"].as_u64().unwrap() - f["blurry"].as_u64().unwrap();
    assert!(
        f["kept"].as_u64().unwrap() * 10 >= sharp * 9,
        "{f}; pieces {}",
        s["pieces"]
    );
    // The stream is BT.709 limited range, tagged, and was decoded so.
    assert_eq!(s["video_decoding"]["decoded_with"], "bt709", "{s}");
    // The marker hunt: this capture shows a marker whole in 2 of its 120 frames, so
    // the sampled frames miss markers; every frame the hunt added shows one of the
    // markers it was looking for whole, and all of them are kept.
    let hunt = &s["marker_hunt"];
    let wanted: Vec<i64> = hunt["wanted"]
        .as_array()
        .unwrap()
        .iter()
        .map(|w| w[0].as_i64().unwrap())
        .collect();
    assert!(!wanted.is_empty(), "{hunt}");
    let kept: Vec<u64> = serde_json::from_slice::<serde_json::Value>(
        &std::fs::read(out.join("capture.json")).unwrap(),
    )
    .unwrap()["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["frame_index"].as_u64().unwrap())
        .collect();
    for a in hunt["added"].as_array().unwrap() {
        let a = a.as_u64().unwrap();
        assert!(kept.contains(&a), "hunted frame {a} not kept: {hunt}");
        let anchors = s["per_frame_anchors"]
            .as_array()
            .unwrap()
            .iter()
            .find(|p| p[0].as_u64() == Some(a))
            .unwrap_or_else(|| panic!("frame {a}: no anchors recorded"));
        assert!(anchors[2].as_u64().unwrap() >= 1, "{anchors}");
    }
    // The relief step: glazed tiles have no relief; the shift curve explains 0.09% of
    // the rigid model's residual here (measured), under the 2% it needs to be applied.
    assert_eq!(s["relief"]["applied"], false, "{}", s["relief"]);
    assert!(
        s["relief"]["gain"].as_f64().is_some_and(|g| g < 0.01),
        "{}",
        s["relief"]
    );
    assert!(
        !s["warnings"].to_string().contains("move with the flash"),
        "{}",
        s["warnings"]
    );
    let checks = s["self_check"].as_array().unwrap();
    assert!(!checks.is_empty());
    assert!(
        checks
            .iter()
            .all(|c| c["shift_mm"].as_f64().is_some_and(|m| m < 1.0)),
        "{checks:?}"
    );
    let v = alignment_accuracy(out.as_path(), &cap);
    let get = |k: &str| v[k].as_f64().unwrap();
    // Issue 18's bounds: median 0.25 px, every frame's p95 under 1 px, camera 2 mm
    // (measured: 0.17, 0.81, 0.61).
    assert!(get("align_error_px_median") < 0.25, "{v}");
    assert!(get("worst_frame_px_p95") < 1.0, "{v}");
    assert!(get("camera_error_mm_median") < 2.0, "{v}");

    // Issue 18: a deliberately misregistered stretch is named, and only it. `svbrdf
    // check` runs the self-check on the written capture: clean, it names no frame; with
    // five consecutive frames' maps moved 3 mm on the plane (what a wrong match set
    // does to a stretch of the sweep), it names exactly those and fails.
    let check = |capture: &Path| {
        svbrdf(&[
            "check",
            "--capture",
            capture.to_str().unwrap(),
            "--reference",
            cap.join("reference.jpg").to_str().unwrap(),
            "--camera",
            cap.join("camera.json").to_str().unwrap(),
        ])
    };
    let o = check(&out);
    assert!(o.status.success(), "{}", stderr(&o));
    // The record is stdout's first line; a summary line follows.
    let record = |o: &std::process::Output| -> serde_json::Value {
        let text = String::from_utf8_lossy(&o.stdout).to_string();
        serde_json::from_str(text.lines().next().unwrap_or("")).unwrap()
    };
    let clean = record(&o);
    assert_eq!(clean["inconsistent"], serde_json::json!([]), "{clean}");
    let mut capture: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("capture.json")).unwrap()).unwrap();
    let frames = capture["frames"].as_array_mut().unwrap();
    assert!(frames.len() >= 15, "{}", frames.len());
    let mut moved = Vec::new();
    for f in &mut frames[8..13] {
        moved.push(f["frame_index"].as_u64().unwrap());
        for s in f["mapping"]["subframes"].as_array_mut().unwrap() {
            // plane_from_pixel, then 0.3 cm along x: row 0 += 0.3 * row 2.
            let h = s["plane_from_pixel"].as_array_mut().unwrap();
            let row2: Vec<f64> = h[2]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_f64().unwrap())
                .collect();
            for (v, r) in h[0].as_array_mut().unwrap().iter_mut().zip(&row2) {
                *v = serde_json::json!(v.as_f64().unwrap() + 0.3 * r);
            }
        }
    }
    let bad = temp_dir().join("misregistered");
    std::fs::create_dir_all(&bad).unwrap();
    std::fs::write(bad.join("capture.json"), capture.to_string()).unwrap();
    let o = check(&bad);
    assert!(!o.status.success());
    let err = stderr(&o);
    assert_eq!(err.matches("error:").count(), 1, "{err}");
    let rec = record(&o);
    assert_eq!(rec["inconsistent"], serde_json::json!(moved), "{rec}");
    for f in rec["frames"].as_array().unwrap() {
        let frame = f["frame"].as_u64().unwrap();
        let shift = f["shift_mm"].as_f64().unwrap_or(0.0);
        if moved.contains(&frame) {
            assert!((shift - 3.0).abs() < 0.5, "frame {frame}: {shift} mm");
        }
    }
}

/// Issue 18: leather's relief makes its texture appear moved towards the flash, and
/// the reference photo (no flash) pulled every frame's map off the plane by that shift
/// (hard-small leather seed 1: median 0.18 px, the same capture with flat normals
/// 0.07). The relief step measures the shift with a rigid camera model, where the
/// markers seen tell it from a change of scale, and corrects the texture
/// correspondences by it: measured 0.180 -> 0.103 px median, 0.707 -> 0.516 px worst
/// frame p95.
#[test]
fn the_relief_shift_of_leather_is_measured_and_corrected() {
    let cap = hard_small("leather", "1");
    let (with, without) = (temp_dir().join("with"), temp_dir().join("without"));
    let o = align(&cap, &with, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let printed = String::from_utf8_lossy(&o.stdout);
    assert!(printed.contains("relief shift:"), "{printed}");
    let o = align(&cap, &without, &["--no-relief"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let rec: serde_json::Value =
        serde_json::from_slice(&std::fs::read(with.join("align.json")).unwrap()).unwrap();
    let r = &rec["summary"]["relief"];
    assert_eq!(r["applied"], true, "{r}");
    // The centre the shift points at, between lens (0) and flash (1): half way on every
    // leather capture measured (session 35).
    let w = r["centre_weight"].as_f64().unwrap();
    assert!(svbrdf_align::relief::CENTRE_WEIGHTS.contains(&w), "{r}");
    // Towards that centre, tens of micrometres where the light's tangent is 0.1-0.4
    // (measured 143, 126, 127, 73 um), and the lens found is the capture's (k1 -0.05
    // rendered: a1 about +0.05).
    let shift: Vec<f64> = r["shift_um"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert!(shift[..4].iter().all(|s| (30.0..300.0).contains(s)), "{r}");
    assert!(
        (0.03..0.07).contains(&r["lens"][0].as_f64().unwrap()),
        "{r}"
    );
    let a = alignment_accuracy(&with, &cap);
    let b = alignment_accuracy(&without, &cap);
    let get = |v: &serde_json::Value, k: &str| v[k].as_f64().unwrap();
    assert!(
        get(&a, "align_error_px_median") < 0.75 * get(&b, "align_error_px_median"),
        "with {a}\nwithout {b}"
    );
    assert!(
        get(&a, "worst_frame_px_p95") < get(&b, "worst_frame_px_p95"),
        "with {a}\nwithout {b}"
    );
}

/// Issue 18: no run succeeds with a frame more than 2 px off. GGX-rendered brushed
/// metal at the tiny size matches only in streaks: each frame's few matches sit in a
/// corner, and before the sub-frame support check the rest of the frame was
/// extrapolated up to 4 cm off (worst frame p95 84 px) while the run succeeded with a
/// 0.004 cm residual. Now those sub-frames are left out, and this capture is refused
/// with a line that says why; should alignment ever succeed here, it must be right.
#[test]
fn streaky_brushed_metal_is_refused_or_right_never_silently_off() {
    let cap = tiny_brushed_metal("brushed", "ggx");
    let out = temp_dir().join("aligned");
    let o = align(&cap, &out, &[]);
    let err = stderr(&o);
    if o.status.success() {
        let v = alignment_accuracy(out.as_path(), &cap);
        assert!(v["worst_frame_px_p95"].as_f64().unwrap() < 2.0, "{v}");
    } else {
        assert!(err.contains("sub-frames were left out"), "{err}");
        assert!(err.contains("of the region is seen by"), "{err}");
        refusal_is_recorded_frame_by_frame(&cap, &out, &err);
    }
}

/// Issue 18 item 2: where the frames sampled at the camera's frame step leave the
/// region thin, the video is aligned again from twice as many frames and the pass that
/// covers more is written; `align.json` records both. The tiny capture sampled every
/// 30th frame: 92% of the region seen by 3 kept frames (measured); every 15th: 99%.
#[test]
fn a_thin_frame_step_is_aligned_again_from_more_frames() {
    let cap = tiny_capture();
    let sparse = temp_dir().join("every-30th");
    std::fs::create_dir_all(&sparse).unwrap();
    for f in ["flash.mp4", "reference.jpg"] {
        std::fs::copy(cap.join(f), sparse.join(f)).unwrap();
    }
    let mut camera = read_json(&cap.join("camera.json"));
    camera["frame_step"] = 30.into();
    std::fs::write(sparse.join("camera.json"), camera.to_string()).unwrap();

    // The first pass alone: registered, thin, and says so.
    let out = temp_dir().join("first-pass");
    let o = align(&sparse, &out, &["--no-densify"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("of the region is seen by at least 3"),
        "{}",
        stderr(&o)
    );
    let first = read_json(&out.join("align.json"));
    assert!(first["summary"]["densified"].is_null());
    let first_coverage = first["summary"]["coverage"].as_f64().unwrap();
    assert!(
        first_coverage < svbrdf_align::GOOD_COVERAGE,
        "{first_coverage}"
    );

    // By default a second pass from every 15th frame, written because it covers more.
    let out = temp_dir().join("densified");
    let o = align(&sparse, &out, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        text.contains("aligned again from every 15th frame"),
        "{text}"
    );
    assert!(text.contains("first pass: decode + features"), "{text}");
    let rec = read_json(&out.join("align.json"));
    let s = &rec["summary"];
    let d = &s["densified"];
    assert_eq!(d["first"]["frame_step"], 30, "{d}");
    assert_eq!(d["first"]["coverage"].as_f64().unwrap(), first_coverage);
    assert_eq!(
        d["first"]["kept"], first["summary"]["frames"]["kept"],
        "{d}"
    );
    assert_eq!(d["finer"]["frame_step"], 15, "{d}");
    assert_eq!(d["kept_finer"], true, "{d}");
    // Everything else in the record is the finer pass's.
    assert_eq!(rec["settings"]["camera"]["frame_step"], 15);
    assert_eq!(d["finer"]["sampled"], s["frames"]["decoded"], "{d}");
    assert_eq!(d["finer"]["kept"], s["frames"]["kept"], "{d}");
    let coverage = s["coverage"].as_f64().unwrap();
    assert_eq!(d["finer"]["coverage"].as_f64().unwrap(), coverage);
    assert!(coverage > first_coverage, "{coverage}");
    let v = alignment_accuracy(&out, cap);
    assert!(v["align_error_px_median"].as_f64().unwrap() < 0.25, "{v}");
    assert!(v["worst_frame_px_p95"].as_f64().unwrap() < 1.0, "{v}");
}

/// Issue 18 item 5: a refused alignment leaves `align.json` (status "refused") and
/// nothing else: the error, the reference camera, and every sampled frame with its
/// blur, whole markers, reference-photo matches against the threshold, its piece of
/// the connectivity map and what became of it, in counts that agree with the printed
/// line. `fit` names the refusal; the next `align` replaces the record without
/// `--overwrite`.
fn refusal_is_recorded_frame_by_frame(cap: &Path, out: &Path, err: &str) {
    let names: Vec<String> = std::fs::read_dir(out)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(
        names,
        ["align.json"],
        "a refused run leaves only its record"
    );
    let r: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("align.json")).unwrap()).unwrap();
    assert_eq!(r["status"], "refused");
    let line = err.lines().find(|l| l.starts_with("error: ")).unwrap();
    assert!(line.contains(r["error"].as_str().unwrap()), "{line}");
    assert!(line.contains(r["tried"].as_str().unwrap()), "{line}");
    assert_eq!(
        r["reference_camera"]["marker_corners_cm"]
            .as_array()
            .unwrap()
            .len(),
        4
    );
    let t = &r["trace"];
    let frames = t["per_frame"].as_array().unwrap();
    // Every sampled frame of the video (every frame_step-th of 90).
    assert!(frames.len() >= 15, "{}", frames.len());
    let needed = t["reference_matches_needed"].as_u64().unwrap();
    assert!(needed > 0);
    let pieces = t["pieces"].as_array().unwrap();
    let mut kept = 0;
    for f in frames {
        let fate = f["fate"].as_str().unwrap();
        kept += usize::from(fate == "kept");
        assert!(f["blur"].as_f64().unwrap() > 0.0, "{f}");
        assert!(f["markers"].is_array(), "{f}");
        if fate != "blurry" {
            // Every sharp frame was matched with the reference photo and lies in a
            // piece of the connectivity map that lists it.
            assert!(f["reference_matches"].is_u64(), "{f}");
            let piece = f["piece"].as_u64().unwrap() as usize;
            assert!(
                pieces[piece].as_array().unwrap().contains(&f["frame"]),
                "{f}"
            );
        }
        if fate == "disconnected" {
            assert!(
                f["markers"].as_array().unwrap().is_empty()
                    || f["reference_matches"].as_u64().unwrap() < needed,
                "{f}"
            );
        }
    }
    assert!(
        line.contains(&format!("{} sampled frames: {kept} kept", frames.len())),
        "{line}"
    );
    assert!(line.contains(&format!("{needed} needed")), "{line}");
    // Refused at the camera's frame step, the video was aligned again from twice as
    // many frames (`densify`); the record and the line describe that second pass, and
    // say what the first gave.
    let d = &t["densified"];
    if !d.is_null() {
        assert_eq!(
            d["finer"]["sampled"].as_u64().unwrap() as usize,
            frames.len()
        );
        assert!(d["first"]["refusal"].is_string(), "{d}");
        assert_eq!(d["kept_finer"], false, "{d}");
        assert!(line.contains("; before: every 5th frame: "), "{line}");
    }
    assert!(
        line.contains(&out.join("align.json").display().to_string()),
        "{line}"
    );

    let o = svbrdf(&[
        "fit",
        "--capture",
        out.to_str().unwrap(),
        "--out",
        temp_dir().join("fit-refused").to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(e.contains("alignment was refused"), "{e}");
    // The record is replaced by the next attempt without --overwrite (here refused
    // the same way: same record).
    let before = std::fs::read(out.join("align.json")).unwrap();
    let o = align(cap, out, &[]);
    assert!(!o.status.success());
    assert!(!stderr(&o).contains("--overwrite"), "{}", stderr(&o));
    let mut a: serde_json::Value = serde_json::from_slice(&before).unwrap();
    let mut b: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("align.json")).unwrap()).unwrap();
    for v in [&mut a, &mut b] {
        v["settings"]["out"] = serde_json::Value::Null;
    }
    assert_eq!(a["trace"], b["trace"]);
}
