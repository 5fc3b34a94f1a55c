//! Still-photo captures end to end on the simulator: flash photos with AprilTag 36h11
//! markers through `align --photos`, `fit` and `eval`, checked against the truth.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use crate::util::{stderr, svbrdf, temp_dir};

fn photo_capture() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let out = temp_dir().join("photos");
        let o = svbrdf(&[
            "synth",
            "--photos",
            "5",
            "--duration",
            "0.5",
            "--marker-dictionary",
            "DICT_APRILTAG_36h11",
            "--seed",
            "4",
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "synth failed: {}", stderr(&o));
        out
    })
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// `svbrdf align --photos` of a folder against the simulated capture's reference.
fn align_photos(photos: &Path, out: &Path) -> std::process::Output {
    let cap = photo_capture();
    svbrdf(&[
        "align",
        "--photos",
        s(photos),
        "--reference",
        s(&cap.join("reference.jpg")),
        "--camera",
        s(&cap.join("photos_camera.json")),
        "--out",
        s(out),
    ])
}

/// The alignment accuracy of an aligned photo set against the simulator's truth.
fn accuracy(aligned: &Path) -> serde_json::Value {
    let o = svbrdf(&[
        "bench",
        "--no-brdf",
        "--align-capture",
        s(aligned),
        "--truth",
        s(photo_capture()),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    serde_json::from_str(String::from_utf8_lossy(&o.stdout).trim()).unwrap()
}

#[test]
fn photo_set_aligns_fits_and_evaluates() {
    let cap = photo_capture();
    let aligned = temp_dir().join("aligned");
    let o = align_photos(&cap.join("photos"), &aligned);
    assert!(o.status.success(), "{}", stderr(&o));
    let c: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(aligned.join("capture.json")).unwrap())
            .unwrap();
    assert_eq!(c["sources"][0]["kind"], "images");
    assert_eq!(c["frames"].as_array().map(Vec::len), Some(5));
    assert!(c["frames"][0]["image"].as_str().unwrap().ends_with(".jpg"));

    // Geometry against the truth.
    let v = accuracy(&aligned);
    let px = v["align_error_px_median"].as_f64().unwrap_or(f64::NAN);
    let mm = v["camera_error_mm_median"].as_f64().unwrap_or(f64::NAN);
    assert!(px < 0.5, "photo alignment {px} px: {v}");
    assert!(mm < 3.0, "photo camera positions {mm} mm: {v}");

    let maps = temp_dir().join("maps");
    let o = svbrdf(&["fit", "--capture", s(&aligned), "--out", s(&maps)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(maps.join("maps/diffuse.exr").is_file());

    let eval = temp_dir().join("eval");
    let o = svbrdf(&[
        "eval",
        "--capture",
        s(&aligned),
        "--holdout",
        "3,4",
        "--out",
        s(&eval),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let e: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(eval.join("eval/eval.json")).unwrap())
            .unwrap();
    assert_eq!(e["fitted_frames"], 3);
    let ssim = e["mean"]["ssim_srgb"].as_f64().unwrap();
    assert!(ssim > 0.7, "held-out SSIM {ssim}: {e}");
    assert!(eval.join("eval/strip_003.png").is_file());
}

#[test]
fn photo_folders_that_cannot_work_are_named() {
    let cap = photo_capture();
    let empty = temp_dir();
    let run = |photos: &Path| align_photos(photos, &temp_dir().join("a"));
    let o = run(&empty);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("expected at least 2"), "{}", stderr(&o));
    // A photo of another size among them.
    let mixed = temp_dir().join("mixed");
    std::fs::create_dir_all(&mixed).unwrap();
    for n in ["photo_00.jpg", "photo_01.jpg"] {
        std::fs::copy(cap.join("photos").join(n), mixed.join(n)).unwrap();
    }
    image::RgbImage::from_pixel(64, 48, image::Rgb([90, 90, 90]))
        .save(mixed.join("photo_02.png"))
        .unwrap();
    let o = run(&mixed);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(e.contains("photo_02.png") && e.contains("64x48"), "{e}");
}

/// A JPEG whose pixels are stored rotated with an EXIF orientation tag (6: turn 90
/// degrees clockwise to view), as phones write portrait photos.
fn jpeg_with_orientation_6(upright: &image::RgbImage) -> Vec<u8> {
    let stored = image::imageops::rotate270(upright);
    let mut jpeg = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 95)
        .encode_image(&stored)
        .unwrap();
    // APP1 "Exif": a big-endian TIFF header and one IFD entry, Orientation = 6.
    let mut app1 = vec![0xFF, 0xE1, 0x00, 0x22];
    app1.extend_from_slice(b"Exif\0\0MM\0\x2A\0\0\0\x08");
    app1.extend_from_slice(&[0, 1, 0x01, 0x12, 0, 3, 0, 0, 0, 1, 0, 6, 0, 0, 0, 0, 0, 0]);
    assert_eq!(app1.len(), 2 + 0x22);
    let mut out = jpeg[..2].to_vec();
    out.extend(app1);
    out.extend_from_slice(&jpeg[2..]);
    out
}

#[test]
fn exif_orientation_is_applied_to_photos() {
    let cap = photo_capture();
    let dir = temp_dir().join("exif");
    std::fs::create_dir_all(&dir).unwrap();
    for k in 0..5 {
        let name = format!("photo_{k:02}.jpg");
        let src = cap.join("photos").join(&name);
        if k == 0 {
            let upright = image::open(&src).unwrap().to_rgb8();
            std::fs::write(dir.join(&name), jpeg_with_orientation_6(&upright)).unwrap();
        } else {
            std::fs::copy(&src, dir.join(&name)).unwrap();
        }
    }
    // Stored sideways: read without the tag, the photo would have another size.
    let raw = image::open(dir.join("photo_00.jpg")).unwrap();
    assert_eq!((raw.width(), raw.height()), (1280, 720));
    let aligned = temp_dir().join("aligned");
    let o = align_photos(&dir, &aligned);
    assert!(o.status.success(), "{}", stderr(&o));
    let v = accuracy(&aligned);
    assert_eq!(v["frames_kept"], 5, "{v}");
    let mm = v["camera_error_mm_p95"].as_f64().unwrap_or(f64::NAN);
    assert!(
        mm < 3.0,
        "camera positions {mm} mm with the rotated photo: {v}"
    );
}
