//! The hostile-input corpus: bad, damaged or unusual inputs fed to every command, as a
//! careless or hostile user would. Every case asserts the exit code, no panic, exactly
//! one line of ours on stderr that names the value (no library noise before it), no
//! output left that looks complete, and every input byte-identical afterwards.
//! docs/RELIABILITY.md lists the cases by group; `SVBRDF_CORPUS_TABLE=1` prints the
//! table.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use crate::util::{temp_dir, tiny_capture};

/// What a case must do.
#[derive(Clone)]
enum Expect {
    /// Exit non-zero with one `error:` line holding every needle (case-insensitive).
    Reject(Vec<String>),
    /// Exit 0 (an unusual but valid input).
    Accept,
}

struct Case {
    group: &'static str,
    name: String,
    args: Vec<String>,
    /// Files and folders the command reads: byte-identical afterwards.
    inputs: Vec<PathBuf>,
    /// The output folder: after a rejection it is absent (or unchanged if it existed).
    out: Option<PathBuf>,
    expect: Expect,
}

fn s(p: &Path) -> String {
    p.to_string_lossy().into_owned()
}

fn reject(needles: &[&str]) -> Expect {
    Expect::Reject(needles.iter().map(|n| n.to_lowercase()).collect())
}

/// The record of a refused alignment, if `out` is a folder holding only that: one
/// `align.json` whose status is "refused".
fn refusal_record(out: &Path) -> Option<serde_json::Value> {
    let names: Vec<_> = std::fs::read_dir(out).ok()?.flatten().collect();
    if names.len() != 1 || names[0].file_name() != "align.json" {
        return None;
    }
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("align.json")).ok()?).ok()?;
    (v["status"] == "refused").then_some(v)
}

/// Hash of every file under `p` (path -> bytes hash), for the byte-identity check.
fn snapshot(p: &Path, into: &mut BTreeMap<PathBuf, Option<u64>>) {
    use std::hash::{Hash, Hasher};
    if p.is_dir() {
        if let Ok(rd) = std::fs::read_dir(p) {
            let mut v: Vec<_> = rd.flatten().map(|e| e.path()).collect();
            v.sort();
            for c in v {
                snapshot(&c, into);
            }
        }
    } else {
        let h = std::fs::read(p).ok().map(|b| {
            let mut h = std::collections::hash_map::DefaultHasher::new();
            b.hash(&mut h);
            h.finish()
        });
        into.insert(p.to_path_buf(), h);
    }
}

fn ffmpeg(args: &[&str]) {
    let o = Command::new("ffmpeg")
        .args(["-v", "error", "-y"])
        .args(args)
        .output()
        .expect("ffmpeg runs");
    assert!(
        o.status.success(),
        "ffmpeg {args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

fn write(p: &Path, bytes: impl AsRef<[u8]>) -> PathBuf {
    std::fs::write(p, bytes).unwrap();
    p.to_path_buf()
}

/// The shared inputs every case starts from.
struct Fixture {
    tiny: PathBuf,
    video: PathBuf,
    reference: PathBuf,
    camera: PathBuf,
    registered: PathBuf,
    capture_json: serde_json::Value,
    maps: PathBuf,
    mg: PathBuf,
}

fn fixture() -> Fixture {
    let tiny = tiny_capture().to_path_buf();
    let root = temp_dir();
    // Fitted maps for export cases (the fit is seconds on tiny).
    let maps = root.join("maps");
    let o = crate::util::svbrdf(&[
        "fit",
        "--capture",
        &s(&tiny.join("registered")),
        "--out",
        &s(&maps),
        "--px-per-cm",
        "8",
    ]);
    assert!(o.status.success(), "{}", crate::util::stderr(&o));
    // A small MaterialGAN-layout folder (4 square PNGs) for import cases.
    let mg = root.join("mg");
    std::fs::create_dir(&mg).unwrap();
    for i in 0..4 {
        ffmpeg(&[
            "-f",
            "lavfi",
            "-i",
            &format!("testsrc=size=128x128:rate=1,hue=h={}", i * 40),
            "-frames:v",
            "1",
            &s(&mg.join(format!("{i:02}.png"))),
        ]);
    }
    write(&mg.join("image_size.txt"), "10\n");
    write(
        &mg.join("camera_pos.txt"),
        "0,0,20\n1,0,20\n0,1,20\n1,1,20\n",
    );
    write(
        &mg.join("light_pos.txt"),
        "0,0,20\n1,0,20\n0,1,20\n1,1,20\n",
    );
    let mut capture_json: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(tiny.join("registered/capture.json")).unwrap(),
    )
    .unwrap();
    // Absolute source path, so that a capture.json anywhere reads the shared video.
    capture_json["sources"][0]["path"] = serde_json::json!(s(&tiny.join("flash.mp4")));
    Fixture {
        video: tiny.join("flash.mp4"),
        reference: tiny.join("reference.jpg"),
        camera: tiny.join("camera.json"),
        registered: tiny.join("registered"),
        tiny,
        capture_json,
        maps,
        mg,
    }
}

/// Builds cases, each with its own folder.
struct Cases<'a> {
    f: &'a Fixture,
    list: Vec<Case>,
    group: &'static str,
}

impl Cases<'_> {
    fn dir(&self) -> PathBuf {
        temp_dir()
    }

    fn add(
        &mut self,
        name: impl Into<String>,
        args: Vec<String>,
        inputs: Vec<PathBuf>,
        out: Option<PathBuf>,
        expect: Expect,
    ) {
        self.list.push(Case {
            group: self.group,
            name: name.into(),
            args,
            inputs,
            out,
            expect,
        });
    }

    /// `align` of a video with the shared reference and camera.
    fn align_video(&mut self, name: &str, video: PathBuf, expect: Expect) {
        let out = self.dir().join("out");
        let args = vec![
            "align".into(),
            "--video".into(),
            s(&video),
            "--reference".into(),
            s(&self.f.reference),
            "--camera".into(),
            s(&self.f.camera),
            "--out".into(),
            s(&out),
        ];
        let inputs = vec![video, self.f.reference.clone(), self.f.camera.clone()];
        self.add(name, args, inputs, Some(out), expect);
    }

    /// `align` of the shared video with another reference photo or camera description.
    fn align_with(&mut self, name: &str, reference: PathBuf, camera: PathBuf, expect: Expect) {
        let out = self.dir().join("out");
        let args = vec![
            "align".into(),
            "--video".into(),
            s(&self.f.video),
            "--reference".into(),
            s(&reference),
            "--camera".into(),
            s(&camera),
            "--out".into(),
            s(&out),
        ];
        let inputs = vec![self.f.video.clone(), reference, camera];
        self.add(name, args, inputs, Some(out), expect);
    }

    /// `fit` of a capture.json written from `edit` of the shared registered capture.
    fn fit_capture(&mut self, name: &str, text: String, extra: &[&str], expect: Expect) {
        let d = self.dir();
        let cap = d.join("cap");
        std::fs::create_dir(&cap).unwrap();
        write(&cap.join("capture.json"), text);
        let out = d.join("out");
        let mut args: Vec<String> = vec![
            "fit".into(),
            "--capture".into(),
            s(&cap),
            "--out".into(),
            s(&out),
        ];
        args.extend(extra.iter().map(|a| a.to_string()));
        self.add(
            name,
            args,
            vec![cap, self.f.video.clone()],
            Some(out),
            expect,
        );
    }

    fn fit_edit(&mut self, name: &str, edit: impl Fn(&mut serde_json::Value), expect: Expect) {
        let mut v = self.f.capture_json.clone();
        edit(&mut v);
        self.fit_capture(name, v.to_string(), &["--px-per-cm", "6"], expect);
    }

    /// `fit` of the shared capture with a `--config` file.
    fn fit_config(&mut self, name: &str, text: &str, expect: Expect) {
        let d = self.dir();
        let cfg = write(&d.join("config.json"), text);
        let out = d.join("out");
        let args = vec![
            "fit".into(),
            "--capture".into(),
            s(&self.f.registered),
            "--config".into(),
            s(&cfg),
            "--out".into(),
            s(&out),
        ];
        self.add(
            name,
            args,
            vec![cfg, self.f.registered.clone()],
            Some(out),
            expect,
        );
    }

    /// Any command with plain arguments; `{out}` in them is replaced by a fresh folder.
    fn cmd(&mut self, name: &str, args: &[&str], inputs: Vec<PathBuf>, expect: Expect) {
        let out = self.dir().join("out");
        let args: Vec<String> = args.iter().map(|a| a.replace("{out}", &s(&out))).collect();
        let has_out = args.iter().any(|a| a == &s(&out));
        self.add(name, args, inputs, has_out.then_some(out), expect);
    }
}

fn video_cases(c: &mut Cases) {
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

fn reference_cases(c: &mut Cases) {
    c.group = "reference photo";
    let f = c.f;
    let d = c.dir();
    let cam = f.camera.clone();
    let rb = std::fs::read(&f.reference).unwrap();
    c.align_with(
        "missing",
        d.join("nope.jpg"),
        cam.clone(),
        reject(&["nope.jpg"]),
    );
    c.align_with(
        "zero-length",
        write(&d.join("empty.jpg"), b""),
        cam.clone(),
        reject(&["empty.jpg", "empty"]),
    );
    for pct in [20, 50, 80, 98] {
        c.align_with(
            &format!("truncated at {pct}%"),
            write(&d.join(format!("t{pct}.jpg")), &rb[..rb.len() * pct / 100]),
            cam.clone(),
            reject(&[&format!("t{pct}.jpg"), "truncated or damaged"]),
        );
    }
    c.align_with(
        "random bytes",
        write(
            &d.join("rnd.jpg"),
            (0..50_000u32)
                .map(|i| (i.wrapping_mul(2_246_822_519) >> 11) as u8)
                .collect::<Vec<u8>>(),
        ),
        cam.clone(),
        reject(&["rnd.jpg"]),
    );
    c.align_with(
        "video renamed .jpg",
        {
            let p = d.join("v.jpg");
            std::fs::copy(&f.video, &p).unwrap();
            p
        },
        cam.clone(),
        reject(&["v.jpg"]),
    );
    let grey = d.join("grey.png");
    ffmpeg(&[
        "-f",
        "lavfi",
        "-i",
        "color=gray:size=1000x750",
        "-frames:v",
        "1",
        &s(&grey),
    ]);
    c.align_with(
        "uniform grey (no markers)",
        grey,
        cam.clone(),
        reject(&["grey.png", "marker"]),
    );
    let tinyimg = d.join("small.jpg");
    ffmpeg(&["-i", &s(&f.reference), "-vf", "scale=32:24", &s(&tinyimg)]);
    c.align_with(
        "32 px wide",
        tinyimg,
        cam.clone(),
        reject(&["32x24", "pixels a side"]),
    );
    // A PNG whose header claims 100000 x 100000 pixels.
    let mut absurd = std::fs::read({
        let p = d.join("base.png");
        ffmpeg(&[
            "-f",
            "lavfi",
            "-i",
            "color=gray:size=100x100",
            "-frames:v",
            "1",
            &s(&p),
        ]);
        p
    })
    .unwrap();
    absurd[16..20].copy_from_slice(&100_000u32.to_be_bytes());
    absurd[20..24].copy_from_slice(&100_000u32.to_be_bytes());
    c.align_with(
        "absurd header (100000 x 100000 PNG)",
        write(&d.join("absurd.png"), absurd),
        cam.clone(),
        reject(&["absurd.png"]),
    );
    // Markers painted out: 3 of 4, and none, with a black box over the image quarters.
    let boxed = |name: &str, filter: &str| {
        let p = d.join(name);
        ffmpeg(&["-i", &s(&f.reference), "-vf", filter, "-q:v", "2", &s(&p)]);
        p
    };
    c.align_with(
        "one marker covered (3 of 4)",
        boxed(
            "three.jpg",
            "drawbox=x=0:y=0:w=iw/2:h=ih/3:color=white:t=fill",
        ),
        cam.clone(),
        reject(&["three.jpg", "marker"]),
    );
    c.align_with(
        "all markers covered",
        boxed("none.jpg", "drawbox=x=0:y=0:w=iw:h=ih:color=white:t=fill"),
        cam.clone(),
        reject(&["none.jpg", "marker"]),
    );
    let dict = write(
        &d.join("cam4x4.json"),
        r#"{"marker_dictionary": "DICT_4X4_50"}"#,
    );
    c.align_with(
        "wrong marker dictionary",
        f.reference.clone(),
        dict,
        reject(&["DICT_4X4_50", "marker"]),
    );
    let kit = d.join("kit");
    let o = crate::util::svbrdf(&["markers", "--out", &s(&kit)]);
    assert!(o.status.success());
    let dup = d.join("dup.jpg");
    ffmpeg(&[
        "-i",
        &s(&f.reference),
        "-i",
        &s(&kit.join("markers.png")),
        "-filter_complex",
        "[1]scale=300:-1[m];[0][m]overlay=10:10",
        "-q:v",
        "2",
        &s(&dup),
    ]);
    c.align_with(
        "a second set of markers (7 found, ids repeated)",
        dup,
        cam.clone(),
        reject(&["dup.jpg", "4 distinct markers", "found ids"]),
    );
    // EXIF orientation 6 (rotate 90 degrees clockwise) in an APP1 segment after SOI.
    let mut exif = vec![0xFF, 0xD8, 0xFF, 0xE1, 0x00, 34];
    exif.extend_from_slice(
        b"Exif\0\0MM\0\x2a\0\0\0\x08\0\x01\x01\x12\0\x03\0\0\0\x01\0\x06\0\0\0\0\0\0",
    );
    exif.extend_from_slice(&rb[2..]);
    c.align_with(
        "EXIF orientation 6 (rotated 90 degrees)",
        write(&d.join("exif6.jpg"), exif),
        cam.clone(),
        Expect::Accept,
    );
    let gray16 = d.join("ref16.png");
    ffmpeg(&["-i", &s(&f.reference), "-pix_fmt", "rgb48be", &s(&gray16)]);
    c.align_with("16-bit PNG", gray16, cam.clone(), Expect::Accept);
}

fn camera_cases(c: &mut Cases) {
    c.group = "camera description";
    let d = c.dir();
    let r = c.f.reference.clone();
    let bad: &[(&str, &str, &[&str])] = &[
        ("empty file", "", &["empty"]),
        ("not JSON", "fov_deg = 70", &["expected"]),
        ("JSON array", "[70]", &["an array"]),
        ("JSON null", "null", &["null"]),
        ("JSON number", "70", &["a number"]),
        (
            "typo fov",
            r#"{"fov": 50}"#,
            &["unknown key \"fov\"", "fov_deg"],
        ),
        (
            "typo marker_size",
            r#"{"marker_size": 2}"#,
            &["marker_size", "marker_size_cm"],
        ),
        (
            "typo flash_offset",
            r#"{"flash_offset": [1,0,0]}"#,
            &["flash_offset", "flash_offset_cm"],
        ),
        (
            "typo frame-step",
            r#"{"frame-step": 2}"#,
            &["frame-step", "frame_step"],
        ),
        ("unknown key", r#"{"iso": 100}"#, &["iso"]),
        ("fov 0", r#"{"fov_deg": 0}"#, &["field of view 0"]),
        (
            "fov negative",
            r#"{"fov_deg": -70}"#,
            &["field of view -70"],
        ),
        ("fov 180", r#"{"fov_deg": 180}"#, &["field of view 180"]),
        ("fov huge", r#"{"fov_deg": 1e300}"#, &["field of view"]),
        (
            "fov out of f64 range",
            r#"{"fov_deg": 1e999}"#,
            &["number out of range"],
        ),
        ("fov as string", r#"{"fov_deg": "70"}"#, &["invalid type"]),
        (
            "fov NaN (not JSON)",
            r#"{"fov_deg": NaN}"#,
            &["expected value"],
        ),
        ("fov null", r#"{"fov_deg": null}"#, &["invalid type"]),
        (
            "marker size 0",
            r#"{"marker_size_cm": 0}"#,
            &["marker size 0"],
        ),
        (
            "marker size negative",
            r#"{"marker_size_cm": -1.6}"#,
            &["marker size -1.6"],
        ),
        ("frame step 0", r#"{"frame_step": 0}"#, &["frame step 0"]),
        (
            "frame step negative",
            r#"{"frame_step": -5}"#,
            &["\"frame_step\"", "invalid value"],
        ),
        (
            "frame step fractional",
            r#"{"frame_step": 2.5}"#,
            &["invalid type"],
        ),
        (
            "flash offset of 2",
            r#"{"flash_offset_cm": [1.4, -0.3]}"#,
            &["invalid length"],
        ),
        (
            "flash offset huge",
            r#"{"flash_offset_cm": [1e6, 0, 0]}"#,
            &["flash offset"],
        ),
        ("readout 1.5 s", r#"{"readout_s": 1.5}"#, &["readout 1.5"]),
        (
            "unknown dictionary",
            r#"{"marker_dictionary": "DICT_9X9_1"}"#,
            &["DICT_9X9_1"],
        ),
    ];
    for (i, (name, text, needles)) in bad.iter().enumerate() {
        let cam = write(&d.join(format!("camera{i}.json")), text);
        c.align_with(name, r.clone(), cam, reject(needles));
    }
    c.align_with(
        "missing file",
        r.clone(),
        d.join("nope.json"),
        reject(&["nope.json"]),
    );
}

fn config_cases(c: &mut Cases) {
    c.group = "fit --config";
    let bad: &[(&str, &str, &[&str])] = &[
        ("empty file", "", &["empty"]),
        ("not JSON", "{min_cluster_px: 3}", &["key must be a string"]),
        ("JSON array", "[]", &["an array"]),
        (
            "unknown key",
            r#"{"speed": "fast"}"#,
            &["unknown key \"speed\""],
        ),
        (
            "typo",
            r#"{"min_cluster": 100}"#,
            &["min_cluster", "min_cluster_px"],
        ),
        ("wrong type", r#"{"refine": "yes"}"#, &["invalid type"]),
        (
            "negative resolution",
            r#"{"px_per_cm": -2}"#,
            &["resolution -2"],
        ),
        (
            "huge resolution",
            r#"{"px_per_cm": 1e6}"#,
            &["resolution 1000000"],
        ),
        (
            "negative intensity",
            r#"{"light_intensity": [-1, 1, 1]}"#,
            &["light intensity"],
        ),
        ("zero saturation", r#"{"saturation": 0}"#, &["saturation 0"]),
        (
            "k range reversed",
            r#"{"k_min": 5, "k_max": 2}"#,
            &["k range"],
        ),
        (
            "min observations 0",
            r#"{"min_observations": 0}"#,
            &["minimum observations 0"],
        ),
        (
            "one validation fold",
            r#"{"select_folds": 1}"#,
            &["validation folds 1", "0 (off) or 2-8"],
        ),
        (
            "tiny validation grid",
            r#"{"select_pixels": 10}"#,
            &["validation pixels 10"],
        ),
    ];
    for (name, text, needles) in bad {
        c.fit_config(name, text, reject(needles));
    }
    c.fit_config("empty object (all defaults)", "{}", Expect::Accept);
}

fn capture_cases(c: &mut Cases) {
    c.group = "registered capture (fit)";
    use serde_json::json;
    type Edit = Box<dyn Fn(&mut serde_json::Value)>;
    let cases: Vec<(&str, Edit, &[&str])> = vec![
        (
            "format wrong",
            Box::new(|v| v["format"] = json!("other")),
            &["format"],
        ),
        (
            "version 2",
            Box::new(|v| v["version"] = json!(2)),
            &["version 2"],
        ),
        (
            "units mm",
            Box::new(|v| v["units"] = json!("mm")),
            &["units"],
        ),
        (
            "px_per_cm 0",
            Box::new(|v| v["px_per_cm"] = json!(0)),
            &["px_per_cm 0"],
        ),
        (
            "px_per_cm negative",
            Box::new(|v| v["px_per_cm"] = json!(-24)),
            &["px_per_cm -24"],
        ),
        (
            "px_per_cm 1e6",
            Box::new(|v| v["px_per_cm"] = json!(1e6)),
            &["px_per_cm 1000000"],
        ),
        (
            "px_per_cm a string",
            Box::new(|v| v["px_per_cm"] = json!("24")),
            &["invalid type"],
        ),
        (
            "region inverted",
            Box::new(|v| v["region"]["x_max"] = json!(-10)),
            &["region"],
        ),
        (
            "region huge",
            Box::new(|v| {
                v["region"]["x_min"] = json!(-1e5);
                v["region"]["x_max"] = json!(1e5)
            }),
            &["region", "at most"],
        ),
        (
            "region missing",
            Box::new(|v| {
                v.as_object_mut().unwrap().remove("region");
            }),
            &["missing field `region`"],
        ),
        (
            "light_intensity negative",
            Box::new(|v| v["light_intensity"] = json!([-320, 320, 320])),
            &["light_intensity", "positive"],
        ),
        (
            "light_intensity zero",
            Box::new(|v| v["light_intensity"] = json!([0, 0, 0])),
            &["light_intensity"],
        ),
        (
            "light_intensity of 2",
            Box::new(|v| v["light_intensity"] = json!([1, 2])),
            &["invalid length"],
        ),
        (
            "no sources",
            Box::new(|v| v["sources"] = json!([])),
            &["no sources"],
        ),
        (
            "source path empty",
            Box::new(|v| v["sources"][0]["path"] = json!("")),
            &["empty path"],
        ),
        (
            "source video missing",
            Box::new(|v| v["sources"][0]["path"] = json!("/nonexistent/flash.mp4")),
            &["/nonexistent/flash.mp4"],
        ),
        (
            "source kind unknown",
            Box::new(|v| v["sources"][0]["kind"] = json!("stream")),
            &["unknown variant"],
        ),
        (
            "source encoding unknown",
            Box::new(|v| v["sources"][0]["encoding"] = json!("log")),
            &["unknown variant"],
        ),
        (
            "frame source out of range",
            Box::new(|v| v["frames"][0]["source"] = json!(3)),
            &["names source 3"],
        ),
        (
            "frame_index missing",
            Box::new(|v| v["frames"][0]["frame_index"] = json!(null)),
            &["no frame_index"],
        ),
        (
            "frame_index past the end",
            Box::new(|v| v["frames"][16]["frame_index"] = json!(5000)),
            &["frame 5000"],
        ),
        (
            "duplicate frame ids",
            Box::new(|v| v["frames"][1]["id"] = json!(0)),
            &["appears twice"],
        ),
        (
            "camera below the plane",
            Box::new(|v| v["frames"][0]["camera_position"][2] = json!(-9)),
            &["above the plane"],
        ),
        (
            "light on the plane",
            Box::new(|v| v["frames"][0]["light_position"][2] = json!(0)),
            &["above the plane"],
        ),
        (
            "position out of f64 range",
            Box::new(|v| v["frames"][0]["camera_position"][0] = json!("x")),
            &["invalid type"],
        ),
        (
            "width 0",
            Box::new(|v| v["frames"][0]["width"] = json!(0)),
            &["size 0x480"],
        ),
        (
            "width huge",
            Box::new(|v| v["frames"][0]["width"] = json!(1_000_000)),
            &["size 1000000x480"],
        ),
        (
            "singular sub-frame homography",
            Box::new(
                |v| v["frames"][0]["mapping"] = json!({"kind": "homographies", "subframes": [{"rect": [0, 0, 269, 479], "plane_from_pixel": [[0,0,0],[0,0,0],[0,0,1]]}]}),
            ),
            &["singular"],
        ),
        (
            "no sub-frames",
            Box::new(|v| {
                v["frames"][0]["mapping"] = json!({"kind": "homographies", "subframes": []})
            }),
            &["sub-frame"],
        ),
        (
            "focal length 0",
            Box::new(|v| v["frames"][0]["mapping"]["intrinsics"]["fx"] = json!(0)),
            &["positive focal"],
        ),
        (
            "mapping kind unknown",
            Box::new(|v| v["frames"][0]["mapping"]["kind"] = json!("fisheye")),
            &["unknown variant"],
        ),
        (
            "frames missing",
            Box::new(|v| {
                v.as_object_mut().unwrap().remove("frames");
            }),
            &["missing field `frames`"],
        ),
        (
            "no frames",
            Box::new(|v| v["frames"] = json!([])),
            &["no frames"],
        ),
    ];
    for (name, edit, needles) in cases {
        c.fit_edit(name, edit, reject(needles));
    }
    c.fit_capture(
        "empty file",
        String::new(),
        &[],
        reject(&["capture.json", "EOF"]),
    );
    c.fit_capture(
        "not JSON",
        "capture".into(),
        &[],
        reject(&["capture.json", "expected"]),
    );
    let nan = c.f.capture_json.to_string().replacen(
        "\"camera_position\":[",
        "\"camera_position\":[NaN,",
        1,
    );
    c.fit_capture(
        "NaN pose (not JSON)",
        nan,
        &[],
        reject(&["capture.json", "expected value"]),
    );
    let text = c.f.capture_json.to_string();
    c.fit_capture(
        "--px-per-cm 0",
        text.clone(),
        &["--px-per-cm", "0"],
        reject(&["resolution 0"]),
    );
    c.fit_capture(
        "--light-intensity -5",
        text.clone(),
        &["--light-intensity", "-5"],
        reject(&["light intensity", "-5"]),
    );
    c.fit_capture(
        "--light-intensity 1,2",
        text.clone(),
        &["--light-intensity", "1,2"],
        reject(&["light intensity"]),
    );
    c.fit_capture(
        "--model phong",
        text.clone(),
        &["--model", "phong"],
        reject(&["phong"]),
    );
    let d = c.dir();
    c.cmd(
        "capture folder missing",
        &["fit", "--capture", &s(&d.join("nope")), "--out", "{out}"],
        vec![],
        reject(&["nope"]),
    );
    c.fit_capture(
        "valid, at 6 px/cm",
        text,
        &["--px-per-cm", "6"],
        Expect::Accept,
    );
}

fn import_eval_cases(c: &mut Cases) {
    c.group = "import, eval and check";
    let f = c.f;
    let d = c.dir();
    let mg = s(&f.mg);
    let (reg, reference, camera) = (s(&f.registered), s(&f.reference), s(&f.camera));
    c.cmd(
        "check: capture folder missing",
        &[
            "check",
            "--capture",
            &s(&d.join("nope")),
            "--reference",
            &reference,
            "--camera",
            &camera,
        ],
        vec![],
        reject(&["nope"]),
    );
    c.cmd(
        "check: reference photo without markers",
        &[
            "check",
            "--capture",
            &reg,
            "--reference",
            &s(&f.mg.join("00.png")),
            "--camera",
            &camera,
        ],
        vec![f.registered.clone(), f.mg.clone()],
        reject(&["00.png"]),
    );
    c.cmd(
        "check: negative offset limit",
        &[
            "check",
            "--capture",
            &reg,
            "--reference",
            &reference,
            "--limit-mm",
            "-1",
        ],
        vec![f.registered.clone()],
        reject(&["-1"]),
    );
    c.cmd(
        "check: the registered capture against its own reference",
        &[
            "check",
            "--capture",
            &reg,
            "--reference",
            &reference,
            "--camera",
            &camera,
        ],
        vec![f.registered.clone(), f.reference.clone(), f.camera.clone()],
        Expect::Accept,
    );
    c.cmd(
        "import: folder missing",
        &[
            "import",
            "--materialgan",
            &s(&d.join("nope")),
            "--out",
            "{out}",
        ],
        vec![],
        reject(&["nope"]),
    );
    c.cmd(
        "import: empty folder",
        &["import", "--materialgan", &s(&c.dir()), "--out", "{out}"],
        vec![],
        reject(&["no numbered images"]),
    );
    let broken = |name: &str, file: &str, text: &str| {
        let b = temp_dir().join(name);
        std::fs::create_dir(&b).unwrap();
        for e in std::fs::read_dir(&f.mg).unwrap().flatten() {
            std::fs::copy(e.path(), b.join(e.file_name())).unwrap();
        }
        write(&b.join(file), text);
        b
    };
    for (name, file, text, needle) in [
        (
            "import: image size 0",
            "image_size.txt",
            "0\n",
            "image width 0",
        ),
        (
            "import: image size text",
            "image_size.txt",
            "wide\n",
            "image_size.txt",
        ),
        (
            "import: 3 camera positions for 4 images",
            "camera_pos.txt",
            "0,0,20\n1,0,20\n0,1,20\n",
            "camera_pos.txt",
        ),
        (
            "import: light position of 2 numbers",
            "light_pos.txt",
            "0,0\n1,0,20\n0,1,20\n1,1,20\n",
            "light_pos.txt",
        ),
        (
            "import: image not a PNG",
            "02.png",
            "not an image",
            "02.png",
        ),
        (
            "import: NaN camera position",
            "camera_pos.txt",
            "nan,0,20\n1,0,20\n0,1,20\n1,1,20\n",
            "not three numbers",
        ),
        (
            "import: infinite light position",
            "light_pos.txt",
            "0,0,20\n1,0,inf\n0,1,20\n1,1,20\n",
            "not three numbers",
        ),
    ] {
        let b = broken(&name.replace([' ', ':'], "_"), file, text);
        c.cmd(
            name,
            &["import", "--materialgan", &s(&b), "--out", "{out}"],
            vec![b.clone()],
            reject(&[needle]),
        );
    }
    c.cmd(
        "import: valid",
        &["import", "--materialgan", &mg, "--out", "{out}"],
        vec![f.mg.clone()],
        Expect::Accept,
    );
    let reg = s(&f.registered);
    for (name, list, needle) in [
        (
            "eval: held-out id not in the capture",
            "3,99",
            "held-out frame 99",
        ),
        (
            "eval: every frame held out",
            "0,1,2,3,4,5,6,7,8,9,10,11,12,13,14,15,16",
            "at least one frame left",
        ),
        ("eval: negative id", "-1", "-1"),
        ("eval: not a number", "a,b", "invalid digit"),
        ("eval: a frame held out twice", "3,3", "3 appears twice"),
    ] {
        c.cmd(
            name,
            &[
                "eval",
                "--capture",
                &reg,
                "--holdout",
                list,
                "--out",
                "{out}",
            ],
            vec![f.registered.clone()],
            reject(&[needle]),
        );
    }
    c.cmd(
        "eval: leave-out 0",
        &[
            "eval",
            "--capture",
            &reg,
            "--leave-out",
            "0",
            "--out",
            "{out}",
        ],
        vec![f.registered.clone()],
        reject(&["0"]),
    );
    c.cmd(
        "eval: a FLIP evaluator that does not exist",
        &[
            "eval",
            "--capture",
            &reg,
            "--holdout",
            "3",
            "--flip",
            "/nonexistent/flip",
            "--out",
            "{out}",
        ],
        vec![f.registered.clone()],
        reject(&["/nonexistent/flip"]),
    );
    c.cmd(
        "eval: leave-out all",
        &[
            "eval",
            "--capture",
            &reg,
            "--leave-out",
            "17",
            "--out",
            "{out}",
        ],
        vec![f.registered.clone()],
        reject(&["17"]),
    );
}

fn output_cases(c: &mut Cases) {
    c.group = "output folders";
    let f = c.f;
    // Each command given an output folder that is, or holds, one of its inputs:
    // refused, and the input untouched, with or without --overwrite.
    let copy_dir = |from: &Path, name: &str| {
        let to = temp_dir().join(name);
        std::fs::create_dir(&to).unwrap();
        for e in std::fs::read_dir(from).unwrap().flatten() {
            if e.path().is_file() {
                std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
            }
        }
        to
    };
    let mg = copy_dir(&f.mg, "mgcopy");
    for ow in [true, false] {
        let tag = if ow { " --overwrite" } else { "" };
        let mut args = vec![
            "import",
            "--materialgan",
            &s_leak(&mg),
            "--out",
            &s_leak(&mg),
        ];
        if ow {
            args.push("--overwrite");
        }
        c.add(
            format!("import --out = the input folder{tag}"),
            args.iter().map(|a| a.to_string()).collect(),
            vec![mg.clone()],
            None,
            reject(if ow {
                &["mgcopy", "input"]
            } else {
                &["--overwrite"]
            }),
        );
    }
    let vdir = copy_dir(&f.tiny, "vcopy");
    let (vv, vr, vc) = (
        vdir.join("flash.mp4"),
        vdir.join("reference.jpg"),
        vdir.join("camera.json"),
    );
    c.add(
        "align --out = the folder holding the video --overwrite",
        vec![
            "align".into(),
            "--video".into(),
            s(&vv),
            "--reference".into(),
            s(&vr),
            "--camera".into(),
            s(&vc),
            "--out".into(),
            s(&vdir),
            "--overwrite".into(),
        ],
        vec![vdir.clone()],
        None,
        reject(&["vcopy", "input"]),
    );
    c.add(
        "align --out = the parent of the video's folder --overwrite",
        vec![
            "align".into(),
            "--video".into(),
            s(&vv),
            "--reference".into(),
            s(&vr),
            "--out".into(),
            s(vdir.parent().unwrap()),
            "--overwrite".into(),
        ],
        vec![vdir.clone()],
        None,
        reject(&["input"]),
    );
    c.add(
        "align --out = the video file --overwrite",
        vec![
            "align".into(),
            "--video".into(),
            s(&vv),
            "--reference".into(),
            s(&vr),
            "--out".into(),
            s(&vv),
            "--overwrite".into(),
        ],
        vec![vdir.clone()],
        None,
        reject(&["flash.mp4"]),
    );
    let cam_only = copy_dir(&f.tiny, "camcopy");
    c.add(
        "align --out = the folder holding camera.json --overwrite",
        vec![
            "align".into(),
            "--video".into(),
            s(&f.video),
            "--reference".into(),
            s(&f.reference),
            "--camera".into(),
            s(&cam_only.join("camera.json")),
            "--out".into(),
            s(&cam_only),
            "--overwrite".into(),
        ],
        vec![cam_only.clone()],
        None,
        reject(&["camera.json", "input"]),
    );
    // fit: the capture's parent, the capture itself, and the video's folder.
    let cap_parent = temp_dir().join("fitparent");
    let cap = cap_parent.join("cap");
    std::fs::create_dir_all(&cap).unwrap();
    write(&cap.join("capture.json"), f.capture_json.to_string());
    for (name, out) in [
        (
            "fit --out = the parent of the capture --overwrite",
            cap_parent.clone(),
        ),
        ("fit --out = the capture folder --overwrite", cap.clone()),
        (
            "fit --out = the folder holding the capture's video --overwrite",
            f.tiny.clone(),
        ),
    ] {
        c.add(
            name,
            vec![
                "fit".into(),
                "--capture".into(),
                s(&cap),
                "--out".into(),
                s(&out),
                "--overwrite".into(),
            ],
            vec![cap_parent.clone(), f.video.clone()],
            None,
            reject(&["input"]),
        );
    }
    let cfgdir = temp_dir().join("cfgdir");
    std::fs::create_dir(&cfgdir).unwrap();
    write(&cfgdir.join("fit.json"), "{}");
    c.add(
        "fit --out = the folder holding --config --overwrite",
        vec![
            "fit".into(),
            "--capture".into(),
            s(&f.registered),
            "--config".into(),
            s(&cfgdir.join("fit.json")),
            "--out".into(),
            s(&cfgdir),
            "--overwrite".into(),
        ],
        vec![cfgdir.clone()],
        None,
        reject(&["fit.json", "input"]),
    );
    c.add(
        "eval --out = the capture folder --overwrite",
        vec![
            "eval".into(),
            "--capture".into(),
            s(&cap),
            "--holdout".into(),
            "3".into(),
            "--out".into(),
            s(&cap),
            "--overwrite".into(),
        ],
        vec![cap_parent.clone()],
        None,
        reject(&["input"]),
    );
    let maps_copy = copy_dir(&f.maps, "mapscopy");
    for sub in ["maps", "fit.json"] {
        let src = f.maps.join(sub);
        if src.is_dir() {
            let dst = maps_copy.join(sub);
            std::fs::create_dir_all(&dst).unwrap();
            for e in std::fs::read_dir(&src).unwrap().flatten() {
                std::fs::copy(e.path(), dst.join(e.file_name())).unwrap();
            }
        }
    }
    let gl = maps_copy.join("gltf");
    std::fs::create_dir_all(&gl).unwrap();
    c.add(
        "export --maps inside --out/gltf --overwrite",
        vec![
            "export".into(),
            "--maps".into(),
            s(&gl),
            "--out".into(),
            s(&maps_copy),
            "--overwrite".into(),
        ],
        vec![maps_copy.clone()],
        None,
        reject(&["input"]),
    );
    let synth_maps = temp_dir().join("smaps");
    std::fs::create_dir(&synth_maps).unwrap();
    ffmpeg(&[
        "-f",
        "lavfi",
        "-i",
        "color=gray:size=64x64",
        "-frames:v",
        "1",
        &s(&synth_maps.join("diffuse.png")),
    ]);
    c.add(
        "synth --out = the --maps folder --overwrite",
        vec![
            "synth".into(),
            "--maps".into(),
            s(&synth_maps),
            "--out".into(),
            s(&synth_maps),
            "--overwrite".into(),
        ],
        vec![synth_maps.clone()],
        None,
        reject(&["smaps", "input"]),
    );
    // Existing outputs without --overwrite, a file as the output, a read-only parent.
    for (name, args) in [
        ("synth into an existing folder", vec!["synth", "--out"]),
        ("markers into an existing folder", vec!["markers", "--out"]),
        (
            "fit into an existing folder",
            vec!["fit", "--capture", s_leak(&f.registered), "--out"],
        ),
        (
            "import into an existing folder",
            vec!["import", "--materialgan", s_leak(&f.mg), "--out"],
        ),
    ] {
        let existing = temp_dir();
        write(&existing.join("keep.txt"), "mine");
        let mut a: Vec<String> = args.iter().map(|x| x.to_string()).collect();
        a.push(s(&existing));
        c.add(
            name,
            a,
            vec![existing.clone(), f.registered.clone(), f.mg.clone()],
            None,
            reject(&["--overwrite"]),
        );
    }
    // export writes gltf/ and mitsuba/ into its folder: an existing folder is fine, an
    // existing gltf/ in it needs --overwrite.
    let existing = temp_dir();
    std::fs::create_dir(existing.join("gltf")).unwrap();
    write(&existing.join("gltf/keep.txt"), "mine");
    c.add(
        "export over an existing gltf/",
        vec![
            "export".into(),
            "--maps".into(),
            s(&f.maps),
            "--out".into(),
            s(&existing),
        ],
        vec![existing.clone(), f.maps.clone()],
        None,
        reject(&["gltf", "--overwrite"]),
    );
    let existing = temp_dir();
    write(&existing.join("keep.txt"), "mine");
    c.add(
        "export into an existing folder (beside other files)",
        vec![
            "export".into(),
            "--maps".into(),
            s(&f.maps),
            "--out".into(),
            s(&existing),
        ],
        vec![f.maps.clone(), existing.join("keep.txt")],
        None,
        Expect::Accept,
    );
    let existing = temp_dir();
    write(&existing.join("keep.txt"), "mine");
    let file_out = write(&temp_dir().join("afile"), "x");
    c.add(
        "markers --out an existing file --overwrite",
        vec![
            "markers".into(),
            "--out".into(),
            s(&file_out),
            "--overwrite".into(),
        ],
        vec![file_out.clone()],
        None,
        reject(&["afile", "it is a file"]),
    );
    let ro = temp_dir().join("readonly");
    std::fs::create_dir(&ro).unwrap();
    let mut perm = std::fs::metadata(&ro).unwrap().permissions();
    std::os::unix::fs::PermissionsExt::set_mode(&mut perm, 0o555);
    std::fs::set_permissions(&ro, perm).unwrap();
    // Root ignores permissions: only meaningful as another user.
    if !is_root() {
        c.add(
            "markers into a read-only folder",
            vec!["markers".into(), "--out".into(), s(&ro.join("kit"))],
            vec![],
            None,
            reject(&["kit", "permission denied"]),
        );
    }
    // A run folder of another capture, without --overwrite.
    let other = crate::util::tiny_run();
    let other_dir = temp_dir().join("runcopy");
    copy_tree(other, &other_dir);
    c.add(
        "run into another input's run folder",
        vec![
            "run".into(),
            "--capture".into(),
            s(&cap),
            "--out".into(),
            s(&other_dir),
        ],
        vec![other_dir.clone(), cap.clone()],
        None,
        reject(&["run of another input", "--overwrite"]),
    );
    c.add(
        "run into a folder holding other files",
        vec![
            "run".into(),
            "--capture".into(),
            s(&cap),
            "--out".into(),
            s(&existing),
        ],
        vec![existing.clone()],
        None,
        reject(&["not an svbrdf run"]),
    );
}

fn flag_cases(c: &mut Cases) {
    c.group = "flags";
    let f = c.f;
    let (v, r, cam) = (s(&f.video), s(&f.reference), s(&f.camera));
    let align = |extra: &[&str]| -> Vec<String> {
        let mut a = vec![
            "align",
            "--video",
            &v,
            "--reference",
            &r,
            "--camera",
            &cam,
            "--out",
            "{out}",
        ];
        a.extend_from_slice(extra);
        a.iter().map(|x| x.to_string()).collect()
    };
    let inputs = vec![f.video.clone(), f.reference.clone(), f.camera.clone()];
    for (name, extra, needle) in [
        (
            "--region with 3 numbers",
            vec!["--region", "1,2,3"],
            "region 1,2,3",
        ),
        ("--region inverted", vec!["--region", "2,-2,-2,2"], "region"),
        (
            "--region not numbers",
            vec!["--region", "a,b,c,d"],
            "invalid float",
        ),
        ("--px-per-cm 0", vec!["--px-per-cm", "0"], "0"),
        ("--px-per-cm 1e9", vec!["--px-per-cm", "1e9"], "1000000000"),
        (
            "--fine-method bogus",
            vec!["--fine-method", "magic"],
            "magic",
        ),
        ("--subframes 5y11", vec!["--subframes", "5y11"], "5y11"),
        ("--subframes 0x0", vec!["--subframes", "0x0"], "sub-frame"),
        ("--overlap-weight -1", vec!["--overlap-weight", "-1"], "-1"),
    ] {
        let args = align(&extra);
        let a: Vec<&str> = args.iter().map(String::as_str).collect();
        c.cmd(name, &a, inputs.clone(), reject(&[needle]));
    }
    for (name, extra) in [
        (
            "--region x0,x1,y0,y1 as documented",
            vec!["--region", "-2.5,2.5,-2.5,2.5"],
        ),
        (
            "--region as four arguments",
            vec!["--region", "-2.5", "2.5", "-2.5", "2.5"],
        ),
    ] {
        let args = align(&extra);
        let a: Vec<&str> = args.iter().map(String::as_str).collect();
        c.cmd(name, &a, inputs.clone(), Expect::Accept);
    }
    c.cmd(
        "markers --dictionary bogus",
        &["markers", "--dictionary", "DICT_BOGUS", "--out", "{out}"],
        vec![],
        reject(&["DICT_BOGUS"]),
    );
    c.cmd(
        "markers --size-cm 0",
        &["markers", "--size-cm", "0", "--out", "{out}"],
        vec![],
        reject(&["0"]),
    );
    c.cmd(
        "markers --size-cm -2",
        &["markers", "--size-cm", "-2", "--out", "{out}"],
        vec![],
        reject(&["-2"]),
    );
    c.cmd(
        "synth --preset huge",
        &["synth", "--preset", "huge", "--out", "{out}"],
        vec![],
        reject(&["huge"]),
    );
    c.cmd(
        "synth --fps 0",
        &["synth", "--fps", "0", "--out", "{out}"],
        vec![],
        reject(&["frame rate 0"]),
    );
    c.cmd(
        "synth --fov 180",
        &["synth", "--fov", "180", "--out", "{out}"],
        vec![],
        reject(&["field of view 180"]),
    );
    c.cmd(
        "synth --duration -1",
        &["synth", "--duration", "-1", "--out", "{out}"],
        vec![],
        reject(&["duration -1"]),
    );
    c.cmd(
        "export --maps missing",
        &[
            "export",
            "--maps",
            &s(&temp_dir().join("nope")),
            "--out",
            "{out}",
        ],
        vec![],
        reject(&["nope"]),
    );
    c.cmd(
        "export --name with a slash",
        &[
            "export",
            "--maps",
            &s(&f.maps),
            "--name",
            "a/b",
            "--out",
            "{out}",
        ],
        vec![f.maps.clone()],
        reject(&["a/b"]),
    );
    c.cmd(
        "view of a folder without a material",
        &["view", &s(&temp_dir())],
        vec![],
        reject(&["material.gltf"]),
    );
}

fn s_leak(p: &Path) -> &'static str {
    Box::leak(s(p).into_boxed_str())
}

fn is_root() -> bool {
    std::fs::metadata("/proc/self")
        .map(|m| std::os::unix::fs::MetadataExt::uid(&m) == 0)
        .unwrap_or(false)
}

pub fn copy_tree(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap().flatten() {
        let p = e.path();
        if p.is_dir() {
            copy_tree(&p, &to.join(e.file_name()));
        } else {
            std::fs::copy(&p, to.join(e.file_name())).unwrap();
        }
    }
}

/// Run one case; `Err` says what it broke.
fn check(case: &Case) -> Result<(), String> {
    let mut before = BTreeMap::new();
    for i in &case.inputs {
        snapshot(i, &mut before);
    }
    let out_existed = case.out.as_ref().is_some_and(|o| o.exists());
    let mut out_before = BTreeMap::new();
    if let Some(o) = &case.out {
        snapshot(o, &mut out_before);
    }
    let o = Command::new(env!("CARGO_BIN_EXE_svbrdf"))
        .args(&case.args)
        .stdin(std::process::Stdio::null())
        .output()
        .map_err(|e| e.to_string())?;
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    if err.contains("panicked") || o.status.code().is_none() || o.status.code() == Some(101) {
        return Err(format!("panic or signal ({:?}): {err}", o.status));
    }
    let mut after = BTreeMap::new();
    for i in &case.inputs {
        snapshot(i, &mut after);
    }
    if before != after {
        return Err("an input changed or was deleted".into());
    }
    match &case.expect {
        Expect::Accept => {
            if !o.status.success() {
                return Err(format!("expected success, got {:?}: {err}", o.status));
            }
        }
        Expect::Reject(needles) => {
            if o.status.success() {
                return Err("expected a refusal, got exit 0".into());
            }
            let lines: Vec<&str> = err.trim().lines().collect();
            if lines.len() != 1 || !lines[0].starts_with("error: ") {
                return Err(format!("expected one `error:` line, got:\n{err}"));
            }
            let low = lines[0].to_lowercase();
            for n in needles {
                if !low.contains(n.as_str()) {
                    return Err(format!("{n:?} not in {:?}", lines[0]));
                }
            }
            if let Some(out) = &case.out {
                let mut out_after = BTreeMap::new();
                snapshot(out, &mut out_after);
                // A refused alignment may leave its record, and only that: a folder
                // holding `align.json` with status "refused" and the printed error
                // (issue 18 item 5), which `fit` refuses by name.
                let record = refusal_record(out);
                if let Some(r) = &record {
                    let error = r["error"].as_str().unwrap_or("");
                    if out_existed || error.is_empty() || !lines[0].contains(error) {
                        return Err(format!(
                            "refusal record {} written over an existing folder, or it does not hold the printed error: {r}",
                            out.display()
                        ));
                    }
                    if !lines[0].contains(&out.join("align.json").display().to_string()) {
                        return Err(format!(
                            "the error line does not name the record: {}",
                            lines[0]
                        ));
                    }
                } else if out.exists() != out_existed || out_after != out_before {
                    return Err(format!(
                        "output {} was left behind or changed",
                        out.display()
                    ));
                }
                if let (Some(parent), Some(name)) = (out.parent(), out.file_name()) {
                    let prefix = format!(".{}.", name.to_string_lossy());
                    if let Ok(rd) = std::fs::read_dir(parent) {
                        for e in rd.flatten() {
                            if e.file_name().to_string_lossy().starts_with(&prefix) {
                                return Err(format!(
                                    "temporary {} left behind",
                                    e.path().display()
                                ));
                            }
                        }
                    }
                }
            }
        }
    }
    Ok(())
}

/// Every case of the corpus, built from the shared tiny capture.
fn corpus() -> Vec<Case> {
    let f = fixture();
    let mut c = Cases {
        f: &f,
        list: Vec::new(),
        group: "",
    };
    video_cases(&mut c);
    reference_cases(&mut c);
    camera_cases(&mut c);
    config_cases(&mut c);
    capture_cases(&mut c);
    import_eval_cases(&mut c);
    output_cases(&mut c);
    flag_cases(&mut c);
    c.list
}

#[test]
fn hostile_input_corpus() {
    let cases = corpus();
    let next = std::sync::atomic::AtomicUsize::new(0);
    let results: std::sync::Mutex<Vec<(usize, Result<(), String>)>> = Default::default();
    std::thread::scope(|scope| {
        for _ in 0..2 {
            scope.spawn(|| loop {
                let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                let Some(case) = cases.get(i) else { return };
                let r = check(case);
                results.lock().unwrap().push((i, r));
            });
        }
    });
    let mut results = results.into_inner().unwrap();
    results.sort_by_key(|r| r.0);
    let mut groups: BTreeMap<&str, (usize, usize, usize)> = BTreeMap::new();
    let mut failures = Vec::new();
    for (i, r) in &results {
        let case = &cases[*i];
        let g = groups.entry(case.group).or_default();
        g.0 += 1;
        match case.expect {
            Expect::Accept => g.2 += 1,
            Expect::Reject(_) => g.1 += 1,
        }
        if let Err(e) = r {
            failures.push(format!("[{}] {}: {e}", case.group, case.name));
        }
    }
    if std::env::var_os("SVBRDF_CORPUS_TABLE").is_some() {
        println!("| group | case | expected |");
        println!("|---|---|---|");
        for case in &cases {
            let e = match &case.expect {
                Expect::Accept => "accepted".to_string(),
                Expect::Reject(n) => format!("refused: {}", n.join(" / ")),
            };
            println!(
                "| {} | {} | {} |",
                case.group,
                case.name.replace('|', "/"),
                e.replace('|', "/")
            );
        }
    }
    eprintln!("hostile-input corpus: {} cases, {} failed; per group (cases, refused, accepted): {groups:?}", cases.len(), failures.len());
    assert!(
        cases.len() >= 150,
        "the corpus has only {} cases",
        cases.len()
    );
    assert!(
        failures.is_empty(),
        "{} of {} cases failed:\n{}",
        failures.len(),
        cases.len(),
        failures.join("\n")
    );
}
