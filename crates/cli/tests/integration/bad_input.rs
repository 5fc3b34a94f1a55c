//! Bad input: one clear line naming the value and the accepted range, non-zero exit,
//! and no output folder left behind.

use crate::util::{stderr, svbrdf, temp_dir};

fn assert_rejected(extra: &[&str], needles: &[&str]) {
    let root = temp_dir();
    let out = root.join("out");
    let mut args = vec!["synth", "--out", out.to_str().unwrap()];
    args.extend_from_slice(extra);
    let o = svbrdf(&args);
    assert!(!o.status.success(), "{extra:?} was accepted");
    let err = stderr(&o);
    assert_eq!(
        err.trim().lines().count(),
        1,
        "{extra:?}: expected one line, got:\n{err}"
    );
    assert!(!err.contains("panicked"), "{err}");
    for n in needles {
        assert!(err.contains(n), "{extra:?}: {n:?} not in {err:?}");
    }
    assert_eq!(
        std::fs::read_dir(&root).unwrap().count(),
        0,
        "{extra:?} left files behind"
    );
}

#[test]
fn unknown_preset() {
    assert_rejected(
        &["--preset", "huge"],
        &["preset", "\"huge\"", "tiny, paper"],
    );
}

#[test]
fn unknown_material() {
    assert_rejected(
        &["--material", "velvet"],
        &["material", "\"velvet\"", "patchwork"],
    );
}

#[test]
fn nonsensical_numbers() {
    assert_rejected(&["--fps", "0"], &["frame rate 0", "greater than 0"]);
    assert_rejected(
        &["--distance-min", "-3"],
        &["minimum distance -3", "greater than 0"],
    );
    assert_rejected(&["--fov", "180"], &["field of view 180", "(0, 180)"]);
    assert_rejected(&["--fov", "0"], &["field of view 0", "(0, 180)"]);
    assert_rejected(&["--duration", "-1"], &["duration -1"]);
    assert_rejected(
        &["--distance-min", "15", "--distance-max", "10"],
        &["maximum distance 10", "at least the minimum distance 15"],
    );
}

#[test]
fn unreadable_map_image() {
    let maps = temp_dir();
    std::fs::write(maps.join("diffuse.png"), b"this is not a png").unwrap();
    let root = temp_dir();
    let out = root.join("out");
    let o = svbrdf(&[
        "synth",
        "--maps",
        maps.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    let err = stderr(&o);
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(
        err.contains("diffuse.png") && err.contains("cannot decode"),
        "{err}"
    );
    assert!(!out.exists());
    assert_eq!(std::fs::read_dir(&root).unwrap().count(), 0);

    let empty = temp_dir();
    let o = svbrdf(&[
        "synth",
        "--maps",
        empty.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("diffuse.png"), "{}", stderr(&o));
}

#[test]
fn existing_output_needs_overwrite() {
    let root = temp_dir();
    let out = root.join("out");
    std::fs::create_dir(&out).unwrap();
    let o = svbrdf(&["synth", "--out", out.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("--overwrite"), "{}", stderr(&o));
}
