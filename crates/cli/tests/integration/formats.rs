//! Video as phones record it beyond 8-bit SDR: 10-bit HLG (BT.2020) and 10-bit SDR
//! HEVC, rotation tags on 10-bit video, and variable frame timing.

use crate::util::{
    align_synth, maps_accuracy, quarter_turns, read_json as read, stderr, svbrdf, temp_dir,
    tiny_capture, NO_SELECTION,
};

/// Synthesize, align and fit a tiny capture; (align.json, fit.json, bench accuracy).
fn pipeline(
    name: &str,
    extra: &[&str],
) -> (serde_json::Value, serde_json::Value, serde_json::Value) {
    let dir = temp_dir().join(name);
    let cap = dir.join("capture");
    let mut args = vec![
        "synth",
        "--preset",
        "tiny",
        "--material",
        "leather",
        "--seed",
        "1",
    ];
    args.extend(extra);
    args.extend(["--out", cap.to_str().unwrap()]);
    let o = svbrdf(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let aligned = dir.join("aligned");
    let o = align_synth(&cap, &aligned, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    // Every format is fitted with the same settings (not chosen per capture on
    // held-out frames), so that the comparison is of the decoded light alone.
    let maps = dir.join("maps");
    let o = svbrdf(&[
        "fit",
        "--capture",
        aligned.to_str().unwrap(),
        "--out",
        maps.to_str().unwrap(),
        NO_SELECTION[0],
        NO_SELECTION[1],
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let acc = maps_accuracy(&maps, &cap);
    (
        read(&aligned.join("align.json")),
        read(&maps.join("fit.json")),
        acc,
    )
}

#[test]
fn hlg_and_pq_captures_are_decoded_to_linear_light_and_clip_less_than_sdr() {
    let (_, sdr_fit, sdr) = pipeline("sdr8", &[]);
    let (hlg_align, hlg_fit, hlg) = pipeline("hlg", &["--video-format", "hevc-hlg"]);
    let v = &hlg_align["summary"]["video_decoding"];
    assert_eq!(v["transfer"], "hlg", "{v}");
    assert_eq!(v["decoder"], "ffmpeg-libraries", "{v}");
    assert_eq!(v["bit_depth"], 10, "{v}");
    assert_eq!(v["from_bt2020"], true, "{v}");
    let d = |a: &serde_json::Value| a["diffuse_rmse"].as_f64().unwrap();
    let clipped = |f: &serde_json::Value| f["summary"]["clipped_near_mirror"].as_f64().unwrap();
    eprintln!(
        "diffuse RMSE SDR {:.4}, HLG {:.4}; clipped near the mirror SDR {:.3}, HLG {:.3}; relighting HLG {}",
        d(&sdr),
        d(&hlg),
        clipped(&sdr_fit),
        clipped(&hlg_fit),
        hlg["relight_relative_rmse"]
    );
    assert!(
        d(&hlg) < 1.25 * d(&sdr) + 0.003,
        "HLG {} against SDR {}",
        d(&hlg),
        d(&sdr)
    );
    assert!(
        clipped(&hlg_fit) < 0.5 * clipped(&sdr_fit),
        "HLG's headroom did not lower the clipped share near the mirror direction"
    );
    // Rendered in the decoder's units, the held-out lights come out at their level.
    for r in hlg["relight_mean_ratio"].as_array().unwrap() {
        let r = r.as_f64().unwrap();
        assert!((0.8..1.25).contains(&r), "{hlg}");
    }
    // PQ (HDR10): the same, through its own curve.
    let (pq_align, pq_fit, pq) = pipeline("pq", &["--video-format", "hevc-pq"]);
    assert_eq!(pq_align["summary"]["video_decoding"]["transfer"], "pq");
    eprintln!(
        "PQ: diffuse RMSE {:.4}, clipped near the mirror {:.3}",
        d(&pq),
        clipped(&pq_fit)
    );
    assert!(
        d(&pq) < 1.25 * d(&sdr) + 0.003,
        "PQ {} against SDR {}",
        d(&pq),
        d(&sdr)
    );
    assert!(clipped(&pq_fit) < 0.5 * clipped(&sdr_fit));
}

#[test]
fn variable_frame_times_reach_the_registered_capture() {
    let dir = temp_dir().join("vfr");
    let cap = dir.join("capture");
    let o = svbrdf(&[
        "synth",
        "--preset",
        "tiny",
        "--video-format",
        "hevc-sdr10",
        "--frame-jitter",
        "0.01",
        "--out",
        cap.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let aligned = dir.join("aligned");
    let o = align_synth(&cap, &aligned, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let truth = read(&cap.join("ground_truth/truth.json"));
    let times: std::collections::HashMap<u64, f64> = truth["streams"][0]["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| (f["index"].as_u64().unwrap(), f["time_s"].as_f64().unwrap()))
        .collect();
    let capture = read(&aligned.join("capture.json"));
    let frames = capture["frames"].as_array().unwrap();
    assert!(frames.len() > 10);
    let mut off_grid = 0;
    for f in frames {
        let i = f["frame_index"].as_u64().unwrap();
        let t = f["time_s"].as_f64().unwrap();
        assert!(
            (t - times[&i]).abs() < 1e-3,
            "frame {i}: {t} against {}",
            times[&i]
        );
        off_grid += usize::from((t - i as f64 / 30.0).abs() > 2e-3);
    }
    assert!(
        off_grid > frames.len() / 2,
        "the frame times are not jittered"
    );
}

#[test]
fn ten_bit_video_turned_by_90_or_270_degrees_comes_out_upright() {
    let cap = tiny_capture();
    let root = temp_dir();
    let ffmpeg = |args: &[&str]| {
        let st = std::process::Command::new("ffmpeg")
            .args(["-v", "error", "-y"])
            .args(args)
            .status()
            .expect("ffmpeg must be installed (the setup script installs it)");
        assert!(st.success());
    };
    let hevc = root.join("hevc10.mp4");
    ffmpeg(&[
        "-i",
        cap.join("flash.mp4").to_str().unwrap(),
        "-frames:v",
        "3",
        "-c:v",
        "libx265",
        "-x265-params",
        "lossless=1:log-level=error",
        "-pix_fmt",
        "yuv420p10le",
        hevc.to_str().unwrap(),
    ]);
    let mut plain = svbrdf_cv::video::VideoReader::open(&hevc).unwrap();
    let fa = plain.read().unwrap().unwrap();
    let (w, h) = (fa.width, fa.height);
    let mut turned = Vec::new();
    for deg in ["90", "270"] {
        let rot = root.join(format!("rot{deg}.mp4"));
        ffmpeg(&[
            "-i",
            hevc.to_str().unwrap(),
            "-c",
            "copy",
            "-metadata:s:v:0",
            &format!("rotate={deg}"),
            rot.to_str().unwrap(),
        ]);
        let mut r = svbrdf_cv::video::VideoReader::open(&rot).unwrap();
        assert_eq!(r.decoding().decoder, "ffmpeg-libraries");
        let fb = r.read().unwrap().unwrap();
        assert_eq!((fb.width, fb.height), (h, w), "{deg}");
        let (cw, ccw) = quarter_turns(&fa, &fb);
        assert!(cw != ccw, "{deg}: not the original turned by a quarter");
        turned.push(cw);
    }
    assert_ne!(
        turned[0], turned[1],
        "90 and 270 degrees turned the same way"
    );
}

/// One rendering, several encodings (issue 20's comparison of formats on identical
/// scenes): `--also-video-format` writes `OUT.FORMAT` folders whose ground truth and
/// registered capture are exactly those of a capture synthesized in that format
/// directly, and whose video is stored in that format.
#[test]
fn also_video_format_writes_the_same_capture_in_another_format() {
    let dir = temp_dir().join("also");
    let main = dir.join("cap");
    let o = svbrdf(&[
        "synth",
        "--preset",
        "tiny",
        "--out",
        main.to_str().unwrap(),
        "--also-video-format",
        "hevc-hlg",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let sibling = dir.join("cap.hevc-hlg");
    assert!(String::from_utf8_lossy(&o.stdout).contains("cap.hevc-hlg"));
    let direct = dir.join("direct");
    let o = svbrdf(&[
        "synth",
        "--preset",
        "tiny",
        "--out",
        direct.to_str().unwrap(),
        "--video-format",
        "hevc-hlg",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    for f in [
        "ground_truth/truth.json",
        "registered/capture.json",
        "camera.json",
    ] {
        assert_eq!(
            read(&sibling.join(f)),
            read(&direct.join(f)),
            "{f} differs from a direct HLG synth"
        );
    }
    let p = svbrdf_cv::probe::probe_video(&sibling.join("flash.mp4")).unwrap();
    assert_eq!(p.transfer.as_deref(), Some("arib-std-b67"), "{p:?}");
    assert_eq!(p.bit_depth, 10, "{p:?}");
    // The main capture is the default format and records what else was written.
    let t = read(&main.join("ground_truth/truth.json"));
    assert_eq!(t["config"]["video"]["also_formats"][0], "hevc-hlg", "{t}");
    // A format twice, or the main one again, is refused in one line.
    let o = svbrdf(&[
        "synth",
        "--preset",
        "tiny",
        "--out",
        dir.join("bad").to_str().unwrap(),
        "--also-video-format",
        "h264-sdr8",
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("extra video formats"), "{}", stderr(&o));
    // The extra folders hold the flash video only: a second camera is refused.
    let o = svbrdf(&[
        "synth",
        "--preset",
        "tiny",
        "--second-camera",
        "--out",
        dir.join("bad2").to_str().unwrap(),
        "--also-video-format",
        "hevc-hlg",
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("second camera"), "{}", stderr(&o));
    assert!(!dir.join("bad2").exists() && !dir.join("bad2.hevc-hlg").exists());
}
