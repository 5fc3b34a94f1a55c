//! Plane ties (issue 18): frames tied to the reference photo without feature matches,
//! and what is left out where the reference photo does not confirm a frame.

use crate::align::{align, alignment_accuracy, tiny_brushed_metal};
use crate::util::{hard_small, read_json, stderr, temp_dir};

/// Issue 18: markers alone do not confirm a registration. Brushed metal matches
/// between frames only along its streaks; with the reference photo's matches left out
/// (`--no-reference-matches`: what happens where the reference photo cannot be
/// matched), the frames hang on four markers and chains of streak matches. Before,
/// such a run succeeded with frames 12 mm off and the self-check unable to verify a
/// single frame; now it is refused in one line naming the unconfirmed frames, while
/// the same capture aligned with the reference photo's matches is registered right.
/// With plane ties (the default), frames the self-check cannot place are not
/// confirmed either: refused, or registered right.
#[test]
fn markers_alone_do_not_confirm_a_registration() {
    let cap = tiny_brushed_metal("brushed-ward", "ward");
    let out = temp_dir().join("markers-and-ties");
    let o = align(&cap, &out, &["--no-reference-matches"]);
    if o.status.success() {
        let v = alignment_accuracy(out.as_path(), &cap);
        assert!(v["worst_frame_px_p95"].as_f64().unwrap() < 1.0, "{v}");
    } else {
        let err = stderr(&o);
        assert_eq!(err.matches("error:").count(), 1, "{err}");
    }
    let out = temp_dir().join("markers-only");
    let o = align(&cap, &out, &["--no-reference-matches", "--no-plane-ties"]);
    let err = stderr(&o);
    if o.status.success() {
        // Should it ever succeed, it must be right.
        let v = alignment_accuracy(out.as_path(), &cap);
        assert!(v["worst_frame_px_p95"].as_f64().unwrap() < 2.0, "{v}");
    } else {
        assert_eq!(err.matches("error:").count(), 1, "{err}");
        assert!(err.contains("cannot be checked"), "{err}");
        assert!(
            err.contains("are placed only through other frames"),
            "{err}"
        );
        let rec = read_json(&out.join("align.json"));
        assert_eq!(rec["status"], "refused");
    }
    let out = temp_dir().join("with-reference");
    let o = align(&cap, &out, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v = alignment_accuracy(out.as_path(), &cap);
    assert!(v["worst_frame_px_p95"].as_f64().unwrap() < 1.0, "{v}");
}

/// Issue 18, item 2: frames tied to the reference photo across the change of light
/// without feature matches. With the reference photo's feature matches left out
/// (`--no-reference-matches`, markers only), hard-small patchwork seed 1 bends by
/// millimetres between the markers (session 20: refused as bent). Plane ties match
/// every frame with the reference photo on the plane (the self-check's 4 cm blocks),
/// solve again, then match at full resolution from there: registered within issue
/// 18's bounds (measured: median 0.09 px, worst frame 0.48 px). Without them the
/// registration is refused in one line.
#[test]
fn plane_ties_register_frames_the_reference_photo_features_do_not_tie() {
    let cap = hard_small("patchwork", "1");
    let out = temp_dir().join("tied");
    let o = align(&cap, &out, &["--no-reference-matches"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let rec = read_json(&out.join("align.json"));
    let ties = &rec["summary"]["plane_ties"];
    assert!(ties["rounds"].as_u64().unwrap() >= 1, "{ties}");
    // Every kept frame is confirmed by full-resolution matches with the reference
    // photo (no feature matches were made).
    let kept = rec["summary"]["frames"]["kept"].as_u64().unwrap();
    assert_eq!(ties["guided_frames"].as_u64().unwrap(), kept, "{ties}");
    assert!(ties["offset_after_mm"].as_f64().unwrap() < 0.25, "{ties}");
    // Frames that show part of a marker get its corners (4 in 3 frames, measured).
    let corners = &rec["summary"]["marker_corners"];
    assert!(corners["corners"].as_u64().unwrap() >= 2, "{corners}");
    assert!(
        corners["partial_corners"].as_u64().unwrap() >= 1,
        "{corners}"
    );
    // And the solve agrees with them: none lies a pixel from where the maps put it
    // (0.16 px median, 0.77 px at most, measured).
    assert!(
        corners["residual_px"][1].as_f64().unwrap() < 1.5,
        "{corners}"
    );
    let v = alignment_accuracy(out.as_path(), &cap);
    let get = |k: &str| v[k].as_f64().unwrap();
    assert!(get("align_error_px_median") < 0.25, "{v}");
    assert!(get("worst_frame_px_p95") < 1.0, "{v}");
    assert!(get("camera_error_mm_median") < 2.0, "{v}");

    let out = temp_dir().join("untied");
    let o = align(&cap, &out, &["--no-reference-matches", "--no-plane-ties"]);
    assert!(!o.status.success());
    let err = stderr(&o);
    assert_eq!(err.matches("error:").count(), 1, "{err}");
}

/// Issue 18: what the reference photo does not confirm holds nothing. Hard-small tiles
/// seed 2 with markers alone (`--no-reference-matches`) leaves 22 of 61 frames
/// unconfirmed. Their correspondences had held the edge of a kept frame next to them,
/// and the kept frames' top sub-frames, where the full-resolution matches with the
/// reference photo found almost none of their features, were turned away with them:
/// worst frame 3.95 px (session 41's build); solved again without the left-out frames,
/// 1.70 px; with those sub-frames left out too, 0.83 px (measured).
#[test]
fn what_the_reference_photo_does_not_confirm_holds_nothing() {
    let cap = hard_small("tiles", "2");
    let out = temp_dir().join("markers-only");
    let o = align(&cap, &out, &["--no-reference-matches"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let rec = read_json(&out.join("align.json"));
    let ties = &rec["summary"]["plane_ties"];
    let unconfirmed = ties["unconfirmed"].as_array().unwrap().len();
    assert!(unconfirmed >= 10, "{ties}");
    assert_eq!(
        rec["summary"]["frames"]["unconfirmed"].as_u64().unwrap(),
        unconfirmed as u64,
        "{rec}"
    );
    // (frame, sub-frames left out, sub-frames it had)
    let trimmed = ties["unmatched_subframes"].as_array().unwrap();
    assert!(!trimmed.is_empty(), "{ties}");
    let printed = String::from_utf8_lossy(&o.stdout);
    assert!(
        printed.contains("left out where under a quarter of their features matched"),
        "{printed}"
    );
    let v = alignment_accuracy(out.as_path(), &cap);
    assert!(v["worst_frame_px_p95"].as_f64().unwrap() < 1.0, "{v}");
}
