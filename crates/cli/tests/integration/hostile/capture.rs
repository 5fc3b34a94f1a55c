//! Hostile registered captures (fit's input) and inputs of `import` and `eval`.

use super::*;

pub(super) fn capture_cases(c: &mut Cases) {
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
        &["--px-per-cm", "6", NO_SELECTION[0], NO_SELECTION[1]],
        Expect::Accept,
    );
}

pub(super) fn import_eval_cases(c: &mut Cases) {
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
