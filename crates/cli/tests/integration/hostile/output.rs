//! Output folders a careless user points at (their inputs, existing files, read-only places) and hostile flag values.

use super::*;

pub(super) fn output_cases(c: &mut Cases) {
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

pub(super) fn flag_cases(c: &mut Cases) {
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
