//! SIFT features, one-to-one matching and robust transform estimation.

use opencv::core::{KeyPoint, Mat, Point2f, Scalar, Vector, CV_32F, CV_8UC1};
use opencv::features2d::{FlannBasedMatcher, SIFT};
use opencv::prelude::*;
use std::sync::Mutex;
use svbrdf_core::image::ImageU8;

use crate::{rgb_to_mat, Context, CvError};

/// Features of one image: positions in pixels (centres at integers) and 128-d SIFT
/// descriptors, row-major.
#[derive(Debug, Clone, Default)]
pub struct Features {
    /// Keypoint positions `[x, y]`.
    pub points: Vec<[f32; 2]>,
    /// Descriptors, 128 floats per point.
    pub descriptors: Vec<f32>,
}

impl Features {
    /// Number of features.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    fn descriptor_mat(&self) -> Result<Mat, CvError> {
        let n = self.points.len() as i32;
        let m = Mat::new_rows_cols_with_data(n, 128, &self.descriptors)
            .ctx(|| "descriptor matrix".into())?;
        m.try_clone().ctx(|| "descriptor matrix".into())
    }
}

/// Grey 8-bit `Mat` of an RGB or single-channel image.
pub(crate) fn grey_mat(img: &ImageU8) -> Result<Mat, CvError> {
    if img.channels == 1 {
        return crate::grey_to_mat(img);
    }
    let bgr = rgb_to_mat(img)?;
    let mut grey = Mat::default();
    opencv::imgproc::cvt_color_def(&bgr, &mut grey, opencv::imgproc::COLOR_BGR2GRAY)
        .ctx(|| "grey".into())?;
    Ok(grey)
}

/// Resize an RGB or single-channel image by `scale` with area averaging (for
/// downscaling).
pub fn resize(img: &ImageU8, scale: f64) -> Result<ImageU8, CvError> {
    let src = if img.channels == 1 {
        crate::grey_to_mat(img)?
    } else {
        rgb_to_mat(img)?
    };
    let mut dst = Mat::default();
    let w = ((img.width as f64) * scale).round().max(1.0) as i32;
    let h = ((img.height as f64) * scale).round().max(1.0) as i32;
    opencv::imgproc::resize(
        &src,
        &mut dst,
        opencv::core::Size::new(w, h),
        0.0,
        0.0,
        opencv::imgproc::INTER_AREA,
    )
    .ctx(|| "resize".into())?;
    if img.channels == 1 {
        crate::mat_to_grey(&dst)
    } else {
        crate::mat_to_rgb(&dst)
    }
}

/// `img` resized by `scale` when `scale < 1`, otherwise a copy of it.
pub fn downscaled(img: &ImageU8, scale: f64) -> Result<ImageU8, CvError> {
    if scale < 1.0 {
        resize(img, scale)
    } else {
        Ok(img.clone())
    }
}

/// Detect up to `max_features` SIFT features, ignoring a disc (`[cx, cy, radius]`, pixels)
/// such as the flash highlight, whose features move with the camera.
/// `contrast` is SIFT's contrast threshold (OpenCV default 0.04; lower finds more
/// features on low-contrast materials).
pub fn sift(
    img: &ImageU8,
    max_features: usize,
    contrast: f64,
    exclude: Option<[f64; 3]>,
) -> Result<Features, CvError> {
    let grey = grey_mat(img)?;
    let mut mask =
        Mat::new_rows_cols_with_default(grey.rows(), grey.cols(), CV_8UC1, Scalar::all(255.0))
            .ctx(|| "mask".into())?;
    if let Some([cx, cy, r]) = exclude {
        opencv::imgproc::circle(
            &mut mask,
            opencv::core::Point::new(cx.round() as i32, cy.round() as i32),
            r.round() as i32,
            Scalar::all(0.0),
            -1,
            opencv::imgproc::LINE_8,
            0,
        )
        .ctx(|| "mask".into())?;
    }
    let mut det =
        SIFT::create(max_features as i32, 3, contrast, 10.0, 1.6).ctx(|| "SIFT".into())?;
    let mut kps = Vector::<KeyPoint>::new();
    let mut desc = Mat::default();
    det.detect_and_compute(&grey, &mask, &mut kps, &mut desc, false)
        .ctx(|| "SIFT detection".into())?;
    let mut out = Features::default();
    if kps.is_empty() {
        return Ok(out);
    }
    if desc.typ() != CV_32F || desc.cols() != 128 {
        return Err(CvError::Invalid {
            what: "SIFT descriptors".into(),
            value: format!("type {}", desc.typ()),
            expected: "128 floats".into(),
        });
    }
    out.points = kps.iter().map(|k| [k.pt().x, k.pt().y]).collect();
    out.descriptors.reserve(kps.len() * 128);
    for r in 0..desc.rows() {
        out.descriptors
            .extend_from_slice(desc.at_row::<f32>(r).ctx(|| "descriptors".into())?);
    }
    Ok(out)
}

const FLANN_TREES: i32 = 1;
const FLANN_CHECKS: i32 = 8;

fn flann_matcher() -> Result<FlannBasedMatcher, CvError> {
    // FLANN's randomised kd-trees draw from OpenCV's per-thread RNG, whose state
    // depends on what that thread ran before: with rayon's work stealing the same pair
    // got different trees (and matches) from run to run. A fixed seed per index makes
    // every match, and so the whole alignment, reproducible.
    opencv::core::set_rng_seed(0x5eed).ctx(|| "seeding OpenCV's RNG".into())?;
    // One randomised kd-tree and 8 leaf checks: a quarter of OpenCV's default cost (4
    // trees, 32 checks) for as many matches passing the ratio test (measured on
    // 3,000-feature frames); the robust estimators after it remove the rest.
    let index = opencv::core::Ptr::new(
        opencv::flann::KDTreeIndexParams::new(FLANN_TREES).ctx(|| "FLANN".into())?,
    );
    let search = opencv::core::Ptr::new(
        opencv::flann::SearchParams::new_1(FLANN_CHECKS, 0.0, true).ctx(|| "FLANN".into())?,
    );
    FlannBasedMatcher::new(&index.into(), &search).ctx(|| "FLANN".into())
}

/// Best train feature per query row that passes Lowe's ratio test.
fn ratio_best(m: &Vector<Vector<opencv::core::DMatch>>, ratio: f32) -> Vec<Option<u32>> {
    m.iter()
        .map(|pair| {
            if pair.len() < 2 {
                return None;
            }
            let (m0, m1) = (pair.get(0).ok()?, pair.get(1).ok()?);
            (m0.distance < ratio * m1.distance).then_some(m0.train_idx as u32)
        })
        .collect()
}

/// A feature set with its search index built once, for matching it against many
/// others (each frame is matched with a dozen neighbours, and every frame with the
/// reference photo): building the kd-tree costs about as much as one search.
pub struct MatchIndex {
    matcher: Mutex<FlannBasedMatcher>,
    descriptors: Mat,
    len: usize,
}

impl MatchIndex {
    /// Build the index of `f`.
    pub fn new(f: &Features) -> Result<Self, CvError> {
        let descriptors = f.descriptor_mat()?;
        let mut matcher = flann_matcher()?;
        if f.len() >= 2 {
            let mut v = Vector::<Mat>::new();
            v.push(descriptors.clone());
            opencv::features2d::DescriptorMatcherTrait::add(&mut matcher, &v)
                .ctx(|| "FLANN index".into())?;
            opencv::features2d::DescriptorMatcherTrait::train(&mut matcher)
                .ctx(|| "FLANN index".into())?;
        }
        Ok(Self {
            matcher: Mutex::new(matcher),
            descriptors,
            len: f.len(),
        })
    }

    /// For each row of `query`, the best of this set's features that passes the ratio
    /// test.
    fn best(&self, query: &Mat, ratio: f32) -> Result<Vec<Option<u32>>, CvError> {
        let mut m = Vector::<Vector<opencv::core::DMatch>>::new();
        if self.len < 2 || query.rows() == 0 {
            return Ok(vec![None; query.rows().max(0) as usize]);
        }
        let mut matcher = self.matcher.lock().map_err(|_| CvError::Invalid {
            what: "FLANN index".into(),
            value: "poisoned".into(),
            expected: "a usable index".into(),
        })?;
        opencv::features2d::DescriptorMatcherTrait::knn_match(
            &mut *matcher,
            query,
            &mut m,
            2,
            &opencv::core::no_array(),
            false,
        )
        .ctx(|| "FLANN matching".into())?;
        Ok(ratio_best(&m, ratio))
    }
}

/// One-to-one matches between two indexed feature sets: nearest neighbours that pass
/// Lowe's ratio test in both directions and agree. Matches are `(index in a, index in
/// b)`.
pub fn match_indexed(
    a: &MatchIndex,
    b: &MatchIndex,
    ratio: f32,
) -> Result<Vec<(u32, u32)>, CvError> {
    if a.len < 2 || b.len < 2 {
        return Ok(Vec::new());
    }
    let ab = b.best(&a.descriptors, ratio)?;
    let ba = a.best(&b.descriptors, ratio)?;
    Ok(ab
        .iter()
        .enumerate()
        .filter_map(|(i, j)| {
            let j = (*j)?;
            (ba.get(j as usize).copied().flatten() == Some(i as u32)).then_some((i as u32, j))
        })
        .collect())
}

/// One-to-one matches of a small feature set `a` against a large indexed set `b`
/// (a frame against the reference photo): `a` is searched in `b`'s index, and only the
/// features of `b` found that way are searched back in `a`.
pub fn match_into(a: &Features, b: &MatchIndex, ratio: f32) -> Result<Vec<(u32, u32)>, CvError> {
    if a.len() < 2 || b.len < 2 {
        return Ok(Vec::new());
    }
    let ab = b.best(&a.descriptor_mat()?, ratio)?;
    let mut hit: Vec<u32> = ab.iter().flatten().copied().collect();
    hit.sort_unstable();
    hit.dedup();
    if hit.is_empty() {
        return Ok(Vec::new());
    }
    let mut rows = Mat::default();
    for &j in &hit {
        rows.push_back(&b.descriptors.row(j as i32).ctx(|| "descriptors".into())?)
            .ctx(|| "descriptors".into())?;
    }
    let back = MatchIndex::new(a)?.best(&rows, ratio)?;
    let ba: std::collections::HashMap<u32, u32> = hit
        .iter()
        .zip(back)
        .filter_map(|(&j, i)| Some((j, i?)))
        .collect();
    Ok(ab
        .iter()
        .enumerate()
        .filter_map(|(i, j)| {
            let j = (*j)?;
            (ba.get(&j) == Some(&(i as u32))).then_some((i as u32, j))
        })
        .collect())
}

/// One-to-one matches between two feature sets: nearest neighbours by FLANN that pass
/// Lowe's ratio test in both directions and agree.
pub fn match_one_to_one(
    a: &Features,
    b: &Features,
    ratio: f32,
) -> Result<Vec<(u32, u32)>, CvError> {
    match_indexed(&MatchIndex::new(a)?, &MatchIndex::new(b)?, ratio)
}

/// A robustly estimated model and which correspondences agree with it.
#[derive(Debug, Clone, PartialEq)]
pub struct Robust<T> {
    /// The model (row-major matrix).
    pub model: T,
    /// Inlier flag per correspondence.
    pub inliers: Vec<bool>,
}

fn points(p: &[[f64; 2]]) -> Vector<Point2f> {
    p.iter()
        .map(|q| Point2f::new(q[0] as f32, q[1] as f32))
        .collect()
}

/// Robust similarity (rotation, uniform scale, translation) from `src` to `dst` by
/// RANSAC with an inlier distance in pixels. Returns the 2x3 matrix and inlier flags.
pub fn estimate_similarity(
    src: &[[f64; 2]],
    dst: &[[f64; 2]],
    inlier_px: f64,
) -> Result<Option<Robust<[[f64; 3]; 2]>>, CvError> {
    if src.len() < 3 {
        return Ok(None);
    }
    let mut mask = Mat::default();
    let m = opencv::calib3d::estimate_affine_partial_2d(
        &points(src),
        &points(dst),
        &mut mask,
        opencv::calib3d::RANSAC,
        inlier_px,
        2000,
        0.995,
        10,
    )
    .ctx(|| "similarity".into())?;
    if m.empty() {
        return Ok(None);
    }
    let mut a = [[0.0; 3]; 2];
    for (r, row) in a.iter_mut().enumerate() {
        for (c, v) in row.iter_mut().enumerate() {
            *v = *m
                .at_2d::<f64>(r as i32, c as i32)
                .ctx(|| "similarity".into())?;
        }
    }
    let inliers = (0..src.len())
        .map(|i| mask.at::<u8>(i as i32).map(|v| *v != 0).unwrap_or(false))
        .collect();
    Ok(Some(Robust { model: a, inliers }))
}

/// Robust homography from `src` to `dst` (MAGSAC++), inlier distance in pixels.
pub fn estimate_homography(
    src: &[[f64; 2]],
    dst: &[[f64; 2]],
    inlier_px: f64,
) -> Result<Option<Robust<[[f64; 3]; 3]>>, CvError> {
    if src.len() < 4 {
        return Ok(None);
    }
    let mut mask = Mat::default();
    let h = opencv::calib3d::find_homography_ext(
        &points(src),
        &points(dst),
        opencv::calib3d::USAC_MAGSAC,
        inlier_px,
        &mut mask,
        2000,
        0.995,
    )
    .ctx(|| "homography".into())?;
    if h.empty() {
        return Ok(None);
    }
    let mut a = [[0.0; 3]; 3];
    for (r, row) in a.iter_mut().enumerate() {
        for (c, v) in row.iter_mut().enumerate() {
            *v = *h
                .at_2d::<f64>(r as i32, c as i32)
                .ctx(|| "homography".into())?;
        }
    }
    let inliers = (0..src.len())
        .map(|i| mask.at::<u8>(i as i32).map(|v| *v != 0).unwrap_or(false))
        .collect();
    Ok(Some(Robust { model: a, inliers }))
}
