//! ArUco / AprilTag markers through OpenCV's contrib `aruco` module (4.6 API).

use opencv::core::{Mat, Point2f, Vector};
use opencv::prelude::*;
use svbrdf_core::image::ImageU8;

use crate::{Context, CvError};

/// Marker dictionaries we accept, named as OpenCV names them.
pub const DICTIONARIES: &[(&str, i32)] = &[
    ("DICT_4X4_50", opencv::aruco::DICT_4X4_50),
    ("DICT_5X5_100", opencv::aruco::DICT_5X5_100),
    ("DICT_6X6_250", opencv::aruco::DICT_6X6_250),
    ("DICT_7X7_250", opencv::aruco::DICT_7X7_250),
    ("DICT_ARUCO_ORIGINAL", opencv::aruco::DICT_ARUCO_ORIGINAL),
    ("DICT_APRILTAG_36h11", opencv::aruco::DICT_APRILTAG_36h11),
];

/// A marker dictionary.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Dictionary {
    name: &'static str,
    id: i32,
}

impl Dictionary {
    /// Look a dictionary up by its OpenCV name (e.g. `DICT_6X6_250`).
    pub fn from_name(name: &str) -> Result<Self, CvError> {
        DICTIONARIES
            .iter()
            .find(|(n, _)| n.eq_ignore_ascii_case(name))
            .map(|&(name, id)| Self { name, id })
            .ok_or_else(|| CvError::Invalid {
                what: "marker dictionary".into(),
                value: format!("{name:?}"),
                expected: format!(
                    "one of {}",
                    DICTIONARIES
                        .iter()
                        .map(|d| d.0)
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            })
    }

    /// The OpenCV name.
    pub fn name(&self) -> &'static str {
        self.name
    }

    /// Cells per marker side including the one-cell border (8 for 6x6 dictionaries).
    pub fn cells(&self) -> usize {
        self.get()
            .map(|d| d.marker_size() as usize + 2)
            .unwrap_or(8)
    }

    fn get(&self) -> Result<opencv::core::Ptr<opencv::aruco::Dictionary>, CvError> {
        opencv::aruco::get_predefined_dictionary_i32(self.id)
            .ctx(|| format!("loading {}", self.name))
    }
}

/// The printed pattern of one marker: `cells x cells` squares including the one-cell
/// black border, row-major from the marker's top-left, `true` = white.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MarkerPattern {
    /// Cells per side, border included.
    pub cells: usize,
    /// Cell colours, row-major, `true` = white.
    pub white: Vec<bool>,
}

/// The pattern of marker `id`, as OpenCV draws it.
pub fn marker_pattern(dict: Dictionary, id: i32) -> Result<MarkerPattern, CvError> {
    let d = dict.get()?;
    let bits = d.marker_size();
    let cells = (bits + 2) as usize;
    let mut img = Mat::default();
    opencv::aruco::draw_marker(&d, id, cells as i32, &mut img, 1)
        .ctx(|| format!("drawing marker {id} of {}", dict.name))?;
    let mut white = Vec::with_capacity(cells * cells);
    for r in 0..cells {
        for c in 0..cells {
            let v = *img
                .at_2d::<u8>(r as i32, c as i32)
                .ctx(|| "reading marker".into())?;
            white.push(v > 127);
        }
    }
    Ok(MarkerPattern { cells, white })
}

/// One detected marker: its id and its four corners in pixels (centres at integers),
/// in OpenCV's order: the marker's own top-left, top-right, bottom-right, bottom-left.
#[derive(Debug, Clone, PartialEq)]
pub struct DetectedMarker {
    /// Marker id in the dictionary.
    pub id: i32,
    /// Corner positions `[x, y]` in pixels.
    pub corners: [[f64; 2]; 4],
}

/// Detect markers with sub-pixel corner refinement.
pub fn detect_markers(img: &ImageU8, dict: Dictionary) -> Result<Vec<DetectedMarker>, CvError> {
    let grey = crate::features::grey_mat(img)?;
    let d = dict.get()?;
    let mut params =
        opencv::aruco::DetectorParameters::create().ctx(|| "detector parameters".into())?;
    params.set_corner_refinement_method(opencv::aruco::CORNER_REFINE_SUBPIX);
    // OpenCV stops refining at 0.1 px steps by default, which leaves corners biased
    // towards the marker centre by a few tenths of a pixel; the world scale comes from
    // the marker size, so refine to convergence.
    params.set_corner_refinement_min_accuracy(0.001);
    params.set_corner_refinement_max_iterations(200);
    let mut corners = Vector::<Vector<Point2f>>::new();
    let mut ids = Vector::<i32>::new();
    let mut rejected = Vector::<Vector<Point2f>>::new();
    opencv::aruco::detect_markers(&grey, &d, &mut corners, &mut ids, &params, &mut rejected)
        .ctx(|| "detecting markers".into())?;
    let mut out = Vec::with_capacity(ids.len());
    for (id, cs) in ids.iter().zip(corners.iter()) {
        if cs.len() != 4 {
            continue;
        }
        let mut c = [[0.0; 2]; 4];
        for (k, p) in cs.iter().enumerate() {
            c[k] = [f64::from(p.x), f64::from(p.y)];
        }
        out.push(DetectedMarker { id, corners: c });
    }
    out.sort_by_key(|m| m.id);
    Ok(out)
}
