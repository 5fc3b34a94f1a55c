//! Hostile videos: damaged, truncated, unusual or mislabelled streams fed to `align` and `run`.

use super::*;

pub(super) fn video_cases(c: &mut Cases) {
    c.group = "video";
    let f = c.f;
    let v = s(&f.video);
    let d = c.dir();
    let bytes = std::fs::read(&f.video).unwrap();
    c.align_video(
        "missing file",
        d.join("nope.mp4"),
        reject(&["nope.mp4", "no such video"]),
    );
    c.align_video(
        "zero-length file",
        write(&d.join("empty.mp4"), b""),
        reject(&["empty.mp4", "empty"]),
    );
    c.align_video("a folder", d.clone(), reject(&["video"]));
    c.align_video(
        "random bytes",
        write(
            &d.join("random.mp4"),
            (0..200_000u32)
                .map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8)
                .collect::<Vec<u8>>(),
        ),
        reject(&["random.mp4", "not a video"]),
    );
    c.align_video(
        "text file",
        write(&d.join("notes.mp4"), "hello\n".repeat(100)),
        reject(&["notes.mp4", "not a video"]),
    );
    c.align_video(
        "JPEG renamed .mp4",
        {
            let p = d.join("photo.mp4");
            std::fs::copy(&f.reference, &p).unwrap();
            p
        },
        reject(&["photo.mp4", "still image"]),
    );
    let png = d.join("frame.png");
    ffmpeg(&["-i", &v, "-frames:v", "1", &s(&png)]);
    c.align_video(
        "PNG renamed .mp4",
        {
            let p = d.join("png.mp4");
            std::fs::copy(&png, &p).unwrap();
            p
        },
        reject(&["png.mp4", "still image"]),
    );
    // moov at the end (as OpenCV writes): truncation leaves no index.
    for pct in [10, 50, 90] {
        c.align_video(
            &format!("truncated at {pct}% (index at the end)"),
            write(
                &d.join(format!("trunc{pct}.mp4")),
                &bytes[..bytes.len() * pct / 100],
            ),
            reject(&["not a video"]),
        );
    }
    // moov at the front (faststart, as phones write): truncation keeps the index.
    let fs = d.join("faststart.mp4");
    ffmpeg(&["-i", &v, "-c", "copy", "-movflags", "+faststart", &s(&fs)]);
    let fsb = std::fs::read(&fs).unwrap();
    for pct in [30, 60, 90] {
        c.align_video(
            &format!("truncated at {pct}% (index at the front)"),
            write(
                &d.join(format!("fstrunc{pct}.mp4")),
                &fsb[..fsb.len() * pct / 100],
            ),
            reject(&["frames decode", "truncated or damaged"]),
        );
    }
    let mut corrupt = fsb.clone();
    let n = corrupt.len();
    for (i, b) in corrupt[n * 45 / 100..n * 47 / 100].iter_mut().enumerate() {
        *b = (i as u8).wrapping_mul(37);
    }
    c.align_video(
        "corrupted in the middle",
        write(&d.join("corrupt.mp4"), corrupt),
        reject(&["frames decode", "damaged"]),
    );
    let one = d.join("one.mp4");
    ffmpeg(&["-i", &v, "-frames:v", "1", "-c:v", "libx264", &s(&one)]);
    c.align_video("1 frame", one, reject(&["one.mp4", "1 frame"]));
    let three = d.join("three.mp4");
    ffmpeg(&["-i", &v, "-frames:v", "3", "-c:v", "libx264", &s(&three)]);
    c.align_video("3 frames", three, reject(&["three.mp4", "3 frames"]));
    let black = d.join("black.mp4");
    ffmpeg(&[
        "-f",
        "lavfi",
        "-i",
        "color=black:size=270x480:rate=30",
        "-t",
        "2",
        "-c:v",
        "libx264",
        "-pix_fmt",
        "yuv420p",
        &s(&black),
    ]);
    c.align_video(
        "black video",
        black,
        reject(&["do not connect", "featureless", "tried: ", "sampled frames"]),
    );
    let still = d.join("still.mp4");
    ffmpeg(&[
        "-loop",
        "1",
        "-i",
        &s(&f.reference),
        "-t",
        "3",
        "-r",
        "30",
        "-vf",
        "scale=270:480",
        "-c:v",
        "libx264",
        "-pix_fmt",
        "yuv420p",
        &s(&still),
    ]);
    c.align_video(
        "still camera",
        still,
        reject(&["barely moved", "cm", "sampled frames", "whole marker"]),
    );
    let hlg = d.join("hlg.mp4");
    ffmpeg(&[
        "-i",
        &v,
        "-c:v",
        "libx265",
        "-x265-params",
        "log-level=error",
        "-pix_fmt",
        "yuv420p10le",
        "-color_trc",
        "arib-std-b67",
        "-color_primaries",
        "bt2020",
        "-colorspace",
        "bt2020nc",
        &s(&hlg),
    ]);
    // HDR and wide-gamut video decode through FFmpeg's libraries to linear light.
    c.align_video("HLG HDR (HEVC 10-bit, BT.2020)", hlg, Expect::Accept);
    let pq = d.join("pq.mp4");
    ffmpeg(&[
        "-i",
        &v,
        "-c:v",
        "libx265",
        "-x265-params",
        "log-level=error",
        "-pix_fmt",
        "yuv420p10le",
        "-color_trc",
        "smpte2084",
        "-color_primaries",
        "bt2020",
        "-colorspace",
        "bt2020nc",
        &s(&pq),
    ]);
    c.align_video("PQ HDR10", pq, Expect::Accept);
    let wide = d.join("bt2020sdr.mp4");
    ffmpeg(&[
        "-i",
        &v,
        "-c:v",
        "libx264",
        "-color_primaries",
        "bt2020",
        "-color_trc",
        "bt709",
        "-colorspace",
        "bt2020nc",
        &s(&wide),
    ]);
    c.align_video("BT.2020 primaries, SDR transfer", wide, Expect::Accept);
    // What cannot be brought to linear light right is named.
    let p3 = d.join("p3.mp4");
    ffmpeg(&[
        "-i",
        &v,
        "-c:v",
        "libx265",
        "-x265-params",
        "log-level=error",
        "-pix_fmt",
        "yuv420p10le",
        "-color_primaries",
        "smpte432",
        "-color_trc",
        "bt709",
        "-colorspace",
        "bt709",
        &s(&p3),
    ]);
    c.align_video(
        "Display P3 primaries",
        p3,
        reject(&["primaries", "SMPTE432", "BT.2020"]),
    );
    let ana = d.join("anamorphic.mp4");
    ffmpeg(&["-i", &v, "-c:v", "libx264", "-vf", "setsar=4/3", &s(&ana)]);
    c.align_video(
        "anamorphic (4:3 pixels)",
        ana,
        reject(&["non-square", "4:3"]),
    );
    let audio = d.join("audio.m4a");
    ffmpeg(&[
        "-f",
        "lavfi",
        "-i",
        "sine=frequency=440:duration=2",
        "-c:a",
        "aac",
        &s(&audio),
    ]);
    c.align_video("audio only", audio, reject(&["no video stream"]));
    // Unusual but valid: decoded right and aligned.
    let hevc10 = d.join("hevc10.mp4");
    ffmpeg(&[
        "-i",
        &v,
        "-c:v",
        "libx265",
        "-x265-params",
        "log-level=error",
        "-pix_fmt",
        "yuv420p10le",
        "-color_trc",
        "bt709",
        "-color_primaries",
        "bt709",
        "-colorspace",
        "bt709",
        &s(&hevc10),
    ]);
    c.align_video("10-bit HEVC SDR (BT.709)", hevc10, Expect::Accept);
    let vp9 = d.join("vp9.webm");
    ffmpeg(&[
        "-i",
        &v,
        "-c:v",
        "libvpx-vp9",
        "-b:v",
        "2M",
        "-deadline",
        "realtime",
        "-cpu-used",
        "8",
        &s(&vp9),
    ]);
    c.align_video("VP9 in WebM", vp9, Expect::Accept);
    let vfr = d.join("vfr.mkv");
    ffmpeg(&[
        "-i",
        &v,
        "-c:v",
        "libx264",
        "-vf",
        "setpts='N/30/TB+0.004*sin(N)/TB'",
        "-fps_mode",
        "vfr",
        &s(&vfr),
    ]);
    c.align_video(
        "variable frame rate (jittered timestamps)",
        vfr,
        Expect::Accept,
    );
    let av1 = d.join("av1.mkv");
    ffmpeg(&[
        "-i",
        &v,
        "-c:v",
        "libsvtav1",
        "-preset",
        "12",
        "-svtav1-params",
        "loglevel=0",
        &s(&av1),
    ]);
    c.align_video("AV1 in Matroska", av1, Expect::Accept);
    let rot = d.join("rot90.mp4");
    ffmpeg(&[
        "-i",
        &v,
        "-c",
        "copy",
        "-metadata:s:v:0",
        "rotate=90",
        &s(&rot),
    ]);
    c.align_video("rotation tag 90", rot, Expect::Accept);
}
