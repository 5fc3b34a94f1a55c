//! Auto-exposure drift: the simulator records it, alignment estimates one gain per
//! frame, and the fit divides it out.

use crate::util::{
    align_synth, maps_accuracy, read_json as read, stderr, svbrdf, temp_dir, NO_SELECTION,
};

#[test]
fn auto_exposure_drift_is_estimated_per_frame_and_divided_out() {
    let dir = temp_dir();
    let cap = dir.join("ae");
    let o = svbrdf(&[
        "synth",
        "--preset",
        "tiny",
        "--material",
        "leather",
        "--auto-exposure",
        "--out",
        cap.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let truth = read(&cap.join("ground_truth/truth.json"));
    let true_gain: std::collections::HashMap<u64, f64> = truth["streams"][0]["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| {
            (
                f["index"].as_u64().unwrap(),
                f["exposure_gain"].as_f64().unwrap(),
            )
        })
        .collect();
    let mut fits = Vec::new();
    for (name, extra) in [("estimated", None), ("fixed", Some("--fixed-exposure"))] {
        let aligned = dir.join(format!("aligned-{name}"));
        let o = align_synth(&cap, &aligned, &extra.map_or(vec![], |e| vec![e]));
        assert!(o.status.success(), "{}", stderr(&o));
        let said = String::from_utf8_lossy(&o.stdout);
        assert!(said.contains("exposure:"), "{said}");
        let summary = read(&aligned.join("align.json"))["summary"]["exposure"].clone();
        let capture = read(&aligned.join("capture.json"));
        let frames = capture["frames"].as_array().unwrap();
        if name == "fixed" {
            assert_eq!(summary["mode"], "fixed", "{summary}");
            assert!(frames.iter().all(|f| f.get("exposure_gain").is_none()));
        } else {
            assert_eq!(summary["mode"], "estimated", "{summary}");
            assert!(aligned.join("exposure.png").is_file());
            // Estimated gains against the simulator's, both relative to their
            // geometric mean: within 0.12 EV for every frame, over a drift of more
            // than 1 EV.
            let pairs: Vec<(f64, f64)> = frames
                .iter()
                .map(|f| {
                    (
                        f["exposure_gain"].as_f64().unwrap(),
                        true_gain[&f["frame_index"].as_u64().unwrap()],
                    )
                })
                .collect();
            let gm = |v: Vec<f64>| (v.iter().map(|x| x.ln()).sum::<f64>() / v.len() as f64).exp();
            let (ge, gt) = (
                gm(pairs.iter().map(|p| p.0).collect()),
                gm(pairs.iter().map(|p| p.1).collect()),
            );
            let ev: Vec<f64> = pairs.iter().map(|p| (p.1 / gt).log2()).collect();
            let spread = ev.iter().cloned().fold(f64::MIN, f64::max)
                - ev.iter().cloned().fold(f64::MAX, f64::min);
            assert!(spread > 1.0, "the simulated drift is only {spread:.2} EV");
            for (e, t) in &pairs {
                let err = ((e / ge) / (t / gt)).log2();
                assert!(err.abs() < 0.12, "gain off by {err:.3} EV: {pairs:?}");
            }
        }
        // Both fitted with the same settings (not chosen per capture on held-out
        // frames), so that the comparison is of the gains alone.
        let maps = dir.join(format!("maps-{name}"));
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
        fits.push(maps_accuracy(&maps, &cap)["diffuse_rmse"].as_f64().unwrap());
    }
    eprintln!(
        "diffuse RMSE with gains {:.4}, assuming fixed exposure {:.4}",
        fits[0], fits[1]
    );
    assert!(
        fits[0] < 0.8 * fits[1],
        "dividing out the gains did not lower the diffuse error: {fits:?}"
    );
}
