//! Diagnostic: detected vs true marker corners in a simulated reference photo.
use std::path::Path;
fn main() {
    let dir = std::env::args().nth(1).expect("synth folder");
    let dir = Path::new(&dir);
    let t: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("ground_truth/truth.json")).unwrap()).unwrap();
    let img = svbrdf_cv::read_image(&dir.join("reference.jpg")).unwrap();
    let found = svbrdf_cv::aruco::detect_markers(&img, svbrdf_cv::aruco::Dictionary::from_name("DICT_6X6_250").unwrap()).unwrap();
    let lum = svbrdf_align::corners::Luminance::new(&img);
    for m in &found {
        let refined = svbrdf_align::corners::refine_corners(&lum, &m.corners.map(|c| svbrdf_core::geometry::Vec2::new(c[0], c[1])), 8);
        let m = &svbrdf_cv::aruco::DetectedMarker { id: m.id, corners: refined.map(|p| [p.x, p.y]) };
        let gt = t["reference"]["marker_corners_px"].as_array().unwrap().iter().find(|e| e[0].as_i64() == Some(m.id as i64)).unwrap();
        let c: Vec<[f64; 2]> = (0..4).map(|k| [gt[1][k][0].as_f64().unwrap(), gt[1][k][1].as_f64().unwrap()]).collect();
        let cx = c.iter().map(|p| p[0]).sum::<f64>() / 4.0;
        let cy = c.iter().map(|p| p[1]).sum::<f64>() / 4.0;
        let mut radial = 0.0;
        for k in 0..4 {
            let (dx, dy) = (m.corners[k][0] - c[k][0], m.corners[k][1] - c[k][1]);
            let (rx, ry) = (c[k][0] - cx, c[k][1] - cy);
            let rn = (rx * rx + ry * ry).sqrt();
            radial += (dx * rx + dy * ry) / rn;
            print!("({dx:.2},{dy:.2}) ");
        }
        let side = ((c[0][0] - c[1][0]).powi(2) + (c[0][1] - c[1][1]).powi(2)).sqrt();
        println!(" id {} side {side:.1} px mean radial offset {:.3} px", m.id, radial / 4.0);
    }
}
