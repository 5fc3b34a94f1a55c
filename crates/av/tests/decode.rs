//! Decoding FFmpeg's own encodes of known colours: 8-bit SDR H.264, 10-bit SDR HEVC,
//! 10-bit HLG and PQ HEVC (BT.2020), rotation metadata and variable frame timing.
#![allow(clippy::unwrap_used)]

use std::io::Write;
use std::path::Path;
use std::process::{Command, Stdio};

use svbrdf_av::AvReader;
use svbrdf_core::color::{mul3, Transfer, BT709_TO_BT2020};

const W: usize = 64;
const H: usize = 48;

/// Linear BT.709 colours of the 8x8 blocks (4 rows of 8 blocks... cycled).
fn colour(block: usize) -> [f64; 3] {
    let base = [
        [0.02, 0.02, 0.02],
        [0.18, 0.18, 0.18],
        [0.5, 0.3, 0.1],
        [0.1, 0.4, 0.6],
        [0.8, 0.8, 0.8],
        [0.3, 0.05, 0.2],
    ];
    let k = base[block % base.len()];
    let s = 1.0 + 0.5 * (block / base.len()) as f64;
    k.map(|v| v * s)
}

/// Write a lossless-ish video of the blocks through FFmpeg, non-linear coding by
/// `t` (linear scaled by `white`, the format's reference white), `frames` frames.
fn encode(out: &Path, t: Transfer, white: f64, ten_bit: bool, hevc: bool, extra: &[&str]) -> bool {
    // A `settb=...` chain in `extra` joins the conversion's filter chain.
    let (pre, extra): (Vec<&str>, Vec<&str>) = extra.iter().partition(|a| a.starts_with("settb"));
    let pre = pre.first().map(|p| format!("{p},")).unwrap_or_default();
    // `full-range` in `extra`: full-range Y'CbCr, tagged so.
    let full = extra.contains(&"full-range");
    let extra: Vec<&str> = extra.into_iter().filter(|a| *a != "full-range").collect();
    let range = if full { "pc" } else { "tv" };
    let vf = |f: &str| -> &'static str {
        Box::leak(
            format!("{pre}{f}")
                .replace("out_range=tv", &format!("out_range={range}"))
                .into_boxed_str(),
        )
    };
    let Ok(mut child) = Command::new("ffmpeg")
        .args(["-v", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgb48le", "-s"])
        .arg(format!("{W}x{H}"))
        .args(["-r", "10", "-i", "-"])
        .args(&extra)
        .args(match (t, hevc) {
            (Transfer::Sdr, false) => vec![
                "-vf", vf("scale=out_color_matrix=bt709:out_range=tv:flags=accurate_rnd+full_chroma_int,format=yuv420p"),
                "-c:v", "libx264", "-qp", "0",
                "-color_primaries", "bt709", "-color_trc", "bt709", "-colorspace", "bt709", "-color_range", range,
            ],
            (Transfer::Sdr, true) => vec![
                "-vf", vf("scale=out_color_matrix=bt709:out_range=tv:flags=accurate_rnd+full_chroma_int,format=yuv420p10le"),
                "-c:v", "libx265", "-x265-params", "lossless=1:log-level=error",
                "-color_primaries", "bt709", "-color_trc", "bt709", "-colorspace", "bt709", "-color_range", range,
            ],
            (Transfer::Hlg, _) => vec![
                "-vf", vf("scale=out_color_matrix=bt2020:out_range=tv:flags=accurate_rnd+full_chroma_int,format=yuv420p10le"),
                "-c:v", "libx265", "-x265-params", "lossless=1:log-level=error",
                "-color_primaries", "bt2020", "-color_trc", "arib-std-b67", "-colorspace", "bt2020nc", "-color_range", range,
            ],
            (Transfer::Pq, _) => vec![
                "-vf", vf("scale=out_color_matrix=bt2020:out_range=tv:flags=accurate_rnd+full_chroma_int,format=yuv420p10le"),
                "-c:v", "libx265", "-x265-params", "lossless=1:log-level=error",
                "-color_primaries", "bt2020", "-color_trc", "smpte2084", "-colorspace", "bt2020nc", "-color_range", range,
            ],
        })
        .args(["-tag:v", if hevc { "hvc1" } else { "avc1" }])
        .arg(out)
        .stdin(Stdio::piped())
        .spawn()
    else {
        return false;
    };
    let _ = ten_bit;
    let wide = t != Transfer::Sdr;
    let mut raw = Vec::with_capacity(W * H * 6);
    for y in 0..H {
        for x in 0..W {
            let lin = colour((y / 8) * 8 + x / 8).map(|v| v * white);
            let lin = if wide {
                mul3(&BT709_TO_BT2020, lin)
            } else {
                lin
            };
            for v in lin {
                let code = (t.from_linear(v) * 65535.0).round() as u16;
                raw.extend_from_slice(&code.to_le_bytes());
            }
        }
    }
    let mut stdin = child.stdin.take().unwrap();
    for _ in 0..5 {
        stdin.write_all(&raw).unwrap();
    }
    drop(stdin);
    child.wait().unwrap().success()
}

/// Decode and compare every block with the linear colour it was made from. The
/// tolerance (relative to the colour plus 2% of white) covers FFmpeg's own
/// R'G'B'-to-Y'CbCr conversion on the way in, which is off by a few codes (grey 128
/// becomes 10-bit Y 499 instead of 504); decoding with the wrong matrix, transfer
/// curve or primaries misses by 10% and more.
fn check(t: Transfer, ten_bit: bool, hevc: bool, tol: f64) {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("v.mp4");
    let white = t.reference_white();
    if !encode(&p, t, white, ten_bit, hevc, &[]) {
        eprintln!("skipped: ffmpeg with libx264/libx265 is not on PATH (apt-get install ffmpeg)");
        return;
    }
    let mut r = AvReader::open(&p).unwrap();
    assert_eq!(r.info().transfer, t);
    assert_eq!(r.info().format.bits, if ten_bit { 10 } else { 8 });
    let mut n = 0;
    let mut worst = 0f64;
    while let Some(f) = r.read().unwrap() {
        for by in 0..H / 8 {
            for bx in 0..W / 8 {
                let want = colour(by * 8 + bx).map(|v| v * white);
                if want.iter().any(|v| *v > 1.0) {
                    continue; // clipped by the format
                }
                // Mean of the block's inner 4x4 pixels (FFmpeg's encoder dithers).
                let mut got = [0f32; 3];
                for dy in 2..6 {
                    for dx in 2..6 {
                        let p = f.rgb.pixel(bx * 8 + dx, by * 8 + dy);
                        for c in 0..3 {
                            got[c] += p[c] / 16.0;
                        }
                    }
                }
                for c in 0..3 {
                    let rel = (f64::from(got[c]) - want[c]).abs() / (want[c] + 0.02 * white);
                    worst = worst.max(rel);
                    if std::env::var("SHOWERR").is_ok() && rel > 0.02 {
                        eprintln!("{t:?} {bx},{by} c{c}: {} vs {} ({rel:.3})", got[c], want[c]);
                    }
                    assert!(rel < tol, "{t:?} block {bx},{by}: {got:?} against {want:?}");
                }
            }
        }
        n += 1;
    }
    assert_eq!(n, 5);
    eprintln!("{t:?}: worst relative error {worst:.4}");
}

#[test]
fn sdr_8_bit_h264_decodes_to_its_linear_colours() {
    check(Transfer::Sdr, false, false, 0.025);
}

#[test]
fn full_range_8_bit_h264_decodes_to_its_linear_colours() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("full.mp4");
    // FFmpeg's own conversion to full range, tagged so (as some Android phones record).
    if !encode(&p, Transfer::Sdr, 1.0, false, false, &["full-range"]) {
        eprintln!("skipped: ffmpeg is not on PATH");
        return;
    }
    let mut r = AvReader::open(&p).unwrap();
    assert!(r.info().full_range, "{:?}", r.info());
    let f = r.read().unwrap().unwrap();
    // White stays white (limited-range decoding would clip it) and a mid grey at its level.
    let px = f.rgb.pixel(4 * 8 + 4, 3 * 8 + 4);
    assert!(px.iter().all(|v| (v - 1.0).abs() < 0.03), "{px:?}");
    let px = f.rgb.pixel(8 + 4, 4);
    assert!(px.iter().all(|v| (v - 0.18).abs() < 0.01), "{px:?}");
}

#[test]
fn sdr_10_bit_hevc_decodes_to_its_linear_colours() {
    check(Transfer::Sdr, true, true, 0.025);
}

#[test]
fn hlg_hevc_decodes_to_scene_light_with_its_headroom() {
    check(Transfer::Hlg, true, true, 0.035);
}

#[test]
fn pq_hevc_decodes_to_display_light() {
    check(Transfer::Pq, true, true, 0.045);
}

#[test]
fn rotation_and_variable_frame_times_come_from_the_stream() {
    let dir = tempfile::tempdir().unwrap();
    let plain = dir.path().join("plain.mp4");
    let p = dir.path().join("r.mp4");
    // Frame n at n/10 s plus a jitter of up to 30 ms.
    let ok = encode(
        &plain,
        Transfer::Sdr,
        1.0,
        false,
        false,
        &[
            "settb=1/1000,setpts=(N/10+0.03*sin(N*1.7))/TB",
            "-fps_mode",
            "passthrough",
            "-enc_time_base:v",
            "1:1000",
        ],
    );
    if !ok {
        eprintln!("skipped: ffmpeg is not on PATH");
        return;
    }
    // The rotation tag as phones write it (a display matrix), without re-encoding.
    let st = Command::new("ffmpeg")
        .args(["-v", "error", "-y", "-i"])
        .arg(&plain)
        .args(["-c", "copy", "-metadata:s:v:0", "rotate=90"])
        .arg(&p)
        .status()
        .unwrap();
    assert!(st.success());
    let mut r = AvReader::open(&p).unwrap();
    assert_eq!(r.info().rotation_deg % 180, 90, "{:?}", r.info());
    assert_eq!(r.info().size(), (H as u32, W as u32));
    // FFmpeg's own upright decode (its autorotation, as players show the video).
    let out = Command::new("ffmpeg")
        .args(["-v", "error", "-i"])
        .arg(&p)
        .args(["-frames:v", "1", "-f", "rawvideo", "-pix_fmt", "rgb24", "-"])
        .output()
        .unwrap();
    assert_eq!(out.stdout.len(), W * H * 3);
    let mut times = Vec::new();
    while let Some(f) = r.read().unwrap() {
        assert_eq!((f.rgb.width, f.rgb.height), (H, W));
        if times.is_empty() {
            let mut diff = 0.0;
            for (k, v) in f.rgb.data.iter().enumerate() {
                let ours = svbrdf_core::color::linear_to_srgb(f64::from(*v)) * 255.0;
                diff += (ours - f64::from(out.stdout[k])).abs();
            }
            let mean = diff / (W * H * 3) as f64;
            assert!(
                mean < 6.0,
                "upright frame differs from FFmpeg's by {mean:.1} codes on average"
            );
        }
        times.push(f.time_s);
    }
    assert_eq!(times.len(), 5);
    for (n, t) in times.iter().enumerate() {
        let want = n as f64 / 10.0 + 0.03 * (n as f64 * 1.7).sin();
        assert!(
            (t - want).abs() < 2e-3,
            "frame {n}: {t} against {want} ({times:?})"
        );
    }
}
