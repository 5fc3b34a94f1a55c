//! Hostile reference photos, phone descriptions and configuration files.

use super::*;

pub(super) fn reference_cases(c: &mut Cases) {
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

pub(super) fn camera_cases(c: &mut Cases) {
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

pub(super) fn config_cases(c: &mut Cases) {
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
        (
            "validation drop ratio below 1",
            r#"{"select_drop_ratio": 0.5}"#,
            &["validation drop ratio 0.5", "0 (off) or above 1"],
        ),
    ];
    for (name, text, needles) in bad {
        c.fit_config(name, text, reject(needles));
    }
    c.fit_config("empty object (all defaults)", "{}", Expect::Accept);
}
