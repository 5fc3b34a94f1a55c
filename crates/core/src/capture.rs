//! The *registered capture*: the on-disk hand-over between geometry and appearance.
//!
//! A folder with `capture.json` (this module's [`RegisteredCapture`]) describing image
//! sources (a video file or still images, with their colour encoding) and, for every
//! kept frame, how its pixels map to the material plane, where its camera was and
//! where the light was. The appearance stage reads only this, so alignment, still-photo
//! import, other tools and the simulator's ground truth can all produce it.
//! Paths inside are relative to the folder holding `capture.json`.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::geometry::{mat3_from_rows, Camera, Intrinsics, Pose, RadialDistortion, Vec2, Vec3};
use crate::homography::Homography;
use crate::maps::Encoding;
use crate::plane::Region;
use crate::CoreError;

/// Value of the `format` field.
pub const CAPTURE_FORMAT: &str = "svbrdf-registered-capture";
/// Version this code writes and reads.
pub const CAPTURE_VERSION: u32 = 1;
/// File name inside a capture folder.
pub const CAPTURE_FILE: &str = "capture.json";
/// The alignment's record beside `capture.json` (written by `svbrdf align`).
pub const ALIGN_RECORD: &str = "align.json";
/// The record's `format` field (records written before session 20 have none).
pub const ALIGN_FORMAT: &str = "svbrdf-align";
/// The record's `version`, raised when a field changes meaning (new fields do not
/// raise it: readers ignore fields they do not know).
pub const ALIGN_VERSION: u32 = 1;
/// Its `status` when alignment refused the capture: the folder then holds only the
/// record (what was tried), no `capture.json`.
pub const ALIGN_STATUS_REFUSED: &str = "refused";

/// The record in `dir` of a refused alignment (`align.json` whose `status` is
/// [`ALIGN_STATUS_REFUSED`]), if there is one.
pub fn refused_alignment(dir: &Path) -> Option<serde_json::Value> {
    crate::fsutil::read_json::<serde_json::Value>(&dir.join(ALIGN_RECORD))
        .ok()
        .filter(|v| v["status"] == ALIGN_STATUS_REFUSED)
}
/// Largest accepted `px_per_cm` (the flags' bound too): 10 um pixels.
pub const MAX_PX_PER_CM: f64 = 1000.0;
/// Largest accepted side of the region, cm.
pub const MAX_REGION_CM: f64 = 500.0;
/// Largest accepted frame side, pixels (8K video is 7680).
pub const MAX_FRAME_SIDE: u32 = 16384;
/// Smallest accepted exposure gain of a frame (6 stops under).
pub const MIN_EXPOSURE_GAIN: f64 = 1.0 / 64.0;
/// Largest accepted exposure gain of a frame (6 stops over).
pub const MAX_EXPOSURE_GAIN: f64 = 64.0;

/// A registered capture (version 1).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RegisteredCapture {
    /// Always [`CAPTURE_FORMAT`].
    pub format: String,
    /// Always [`CAPTURE_VERSION`].
    pub version: u32,
    /// Who wrote it (e.g. `svbrdf-synth ground truth`, `svbrdf align`).
    pub producer: String,
    /// Length unit of every position: always `"cm"`.
    pub units: String,
    /// The region of the plane to reconstruct (cm).
    pub region: Region,
    /// Suggested output resolution, pixels per cm.
    pub px_per_cm: f64,
    /// Light intensity `I` of eq. (9) in linear pixel units * cm^2 per channel, if known
    /// (the simulator knows it; a real capture does not, and fitted albedos are then
    /// relative to an intensity of 1).
    pub light_intensity: Option<[f64; 3]>,
    /// Image sources, referenced by index from frames.
    pub sources: Vec<Source>,
    /// Kept frames.
    pub frames: Vec<Frame>,
}

/// Where frame pixels come from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Source {
    /// `video`: one video file, frames addressed by index; `images`: one file per frame.
    pub kind: SourceKind,
    /// Video file (for `video`) or folder (for `images`), relative to the capture folder.
    pub path: String,
    /// Transfer curve of the stored pixel values (phone video and JPEG: `srgb`).
    pub encoding: Encoding,
    /// Camera stream: 0 for the flash camera, 1 for a second (no-flash) camera.
    pub stream: u32,
    /// For a video: how its frames were found to be coded and are turned into linear
    /// light (a record for people; decoders read the stream's own tags again).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub video: Option<VideoCoding>,
}

/// How a video source is coded and decoded.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct VideoCoding {
    /// Codec (`h264`, `hevc`, ...).
    pub codec: String,
    /// Pixel format (`yuv420p`, `yuv420p10le`, ...).
    pub pix_fmt: String,
    /// Transfer curve applied: `sdr` (the sRGB curve), `hlg` or `pq`.
    pub transfer: crate::color::Transfer,
    /// Whether BT.2020 primaries are converted to BT.709 in linear light.
    pub from_bt2020: bool,
    /// Bits per sample kept through to the observations (8 or 10).
    pub bits: u32,
    /// `opencv` (8-bit SDR) or `ffmpeg-libraries` (10-bit and HDR).
    pub decoder: String,
}

/// Kind of image source.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SourceKind {
    /// A video file.
    Video,
    /// A folder of still images.
    Images,
}

/// One kept frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Frame {
    /// Unique id within the capture.
    pub id: u32,
    /// Index into `sources`.
    pub source: usize,
    /// Frame number in the video (0-based, decode order), for video sources.
    pub frame_index: Option<u64>,
    /// File name inside the source folder, for image sources.
    pub image: Option<String>,
    /// Capture time in seconds on the flash camera's clock, if known.
    pub time_s: Option<f64>,
    /// Image width in pixels (after applying rotation metadata).
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// From frame pixels to plane points.
    pub mapping: FrameMapping,
    /// Camera centre, cm.
    pub camera_position: [f64; 3],
    /// Light (flash) position, cm.
    pub light_position: [f64; 3],
    /// Relative exposure of the frame: its linear pixel values are this gain times what
    /// they would be at gain 1 (auto-exposure, flicker, a torch that dims as it warms).
    /// Absent: 1 (fixed exposure, or not estimated). The appearance stage divides the
    /// frame's observations by it. Unitless, in [`MIN_EXPOSURE_GAIN`, `MAX_EXPOSURE_GAIN`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exposure_gain: Option<f64>,
}

impl Frame {
    /// The frame's exposure gain (1 when none is recorded).
    pub fn gain(&self) -> f64 {
        self.exposure_gain.unwrap_or(1.0)
    }
}

/// How a frame's pixels map to the plane.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum FrameMapping {
    /// A calibrated camera: intrinsics, radial distortion and orientation; the centre is
    /// the frame's `camera_position`.
    Pinhole {
        /// Intrinsics in pixels.
        intrinsics: Intrinsics,
        /// Radial distortion.
        distortion: RadialDistortion,
        /// world_from_camera rotation, row-major.
        rotation: [[f64; 3]; 3],
    },
    /// Piecewise homographies (the paper's sub-frames): each pixel rectangle has its own
    /// map from frame pixels to plane cm; where rectangles overlap, results are averaged.
    Homographies {
        /// The sub-frames.
        subframes: Vec<SubFrame>,
    },
}

/// A rectangle of frame pixels and its homography to the plane.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SubFrame {
    /// Inclusive pixel bounds `[x0, y0, x1, y1]` in continuous coordinates.
    pub rect: [f64; 4],
    /// plane_from_pixel homography, row-major.
    pub plane_from_pixel: [[f64; 3]; 3],
}

impl SubFrame {
    fn contains(&self, p: Vec2) -> bool {
        p.x >= self.rect[0] && p.y >= self.rect[1] && p.x <= self.rect[2] && p.y <= self.rect[3]
    }
}

/// A frame mapping made ready for repeated evaluation.
#[derive(Debug, Clone)]
pub enum PreparedMapping {
    /// A camera.
    Camera(Camera),
    /// Sub-frames with forward and inverse homographies.
    Homographies(Vec<PreparedSubFrame>),
}

/// A sub-frame ready for evaluation.
#[derive(Debug, Clone)]
pub struct PreparedSubFrame {
    /// The sub-frame.
    pub subframe: SubFrame,
    /// plane_from_pixel.
    pub forward: Homography,
    /// pixel_from_plane.
    pub inverse: Homography,
    /// Plane bounding box `[x_min, y_min, x_max, y_max]` (cm) of the rectangle's image,
    /// slightly enlarged: `plane_to_pixel` tests it before applying the inverse, which
    /// makes the inverse mapping of a 55-sub-frame frame about ten times cheaper.
    pub plane_bbox: [f64; 4],
}

impl PreparedMapping {
    /// Build from a frame.
    pub fn new(frame: &Frame) -> Result<Self, CoreError> {
        match &frame.mapping {
            FrameMapping::Pinhole {
                intrinsics,
                distortion,
                rotation,
            } => Ok(Self::Camera(Camera {
                intrinsics: *intrinsics,
                distortion: *distortion,
                pose: Pose {
                    rotation: mat3_from_rows(rotation),
                    centre: Vec3::from(frame.camera_position),
                },
            })),
            FrameMapping::Homographies { subframes } => {
                let mut out = Vec::with_capacity(subframes.len());
                for s in subframes {
                    let h = Homography(mat3_from_rows(&s.plane_from_pixel));
                    let inv = h.inverse().ok_or_else(|| {
                        CoreError::Degenerate(format!(
                            "frame {}: singular sub-frame homography",
                            frame.id
                        ))
                    })?;
                    let [x0, y0, x1, y1] = s.rect;
                    let mut bb = [f64::INFINITY, f64::INFINITY, -f64::INFINITY, -f64::INFINITY];
                    // Edge midpoints as well as corners: a homography can bow edges only
                    // when its horizon is near, which the pose check of alignment rejects.
                    for (u, v) in [
                        (0.0, 0.0),
                        (0.5, 0.0),
                        (1.0, 0.0),
                        (1.0, 0.5),
                        (1.0, 1.0),
                        (0.5, 1.0),
                        (0.0, 1.0),
                        (0.0, 0.5),
                    ] {
                        let p = h
                            .apply(Vec2::new(x0 + u * (x1 - x0), y0 + v * (y1 - y0)))
                            .ok_or_else(|| {
                                CoreError::Degenerate(format!(
                                    "frame {}: sub-frame corner maps to infinity",
                                    frame.id
                                ))
                            })?;
                        bb = [
                            bb[0].min(p.x),
                            bb[1].min(p.y),
                            bb[2].max(p.x),
                            bb[3].max(p.y),
                        ];
                    }
                    let pad = 1e-6 + 1e-3 * (bb[2] - bb[0]).max(bb[3] - bb[1]);
                    out.push(PreparedSubFrame {
                        subframe: s.clone(),
                        forward: h,
                        inverse: inv,
                        plane_bbox: [bb[0] - pad, bb[1] - pad, bb[2] + pad, bb[3] + pad],
                    });
                }
                Ok(Self::Homographies(out))
            }
        }
    }

    /// Plane point (cm) seen at a frame pixel.
    pub fn pixel_to_plane(&self, p: Vec2) -> Option<Vec2> {
        match self {
            Self::Camera(c) => c.pixel_to_plane(p),
            Self::Homographies(subs) => average(
                subs.iter()
                    .filter(|s| s.subframe.contains(p))
                    .filter_map(|s| s.forward.apply(p)),
            ),
        }
    }

    /// Frame pixel that sees a plane point (cm); `None` outside the image.
    pub fn plane_to_pixel(&self, q: Vec2) -> Option<Vec2> {
        match self {
            Self::Camera(c) => camera_pixel(c, q),
            Self::Homographies(subs) => average(
                subs.iter()
                    .filter(|s| {
                        let b = &s.plane_bbox;
                        q.x >= b[0] && q.y >= b[1] && q.x <= b[2] && q.y <= b[3]
                    })
                    .filter_map(|s| s.pixel(q)),
            ),
        }
    }
}

/// [`PreparedMapping::plane_to_pixel`] along one row of plane points (one `y`): the
/// sub-frames whose plane bounding box spans the row are found once, not per point.
#[derive(Debug, Clone)]
pub enum RowMapping<'a> {
    /// A camera.
    Camera(&'a Camera),
    /// The sub-frames that can see the row, in the mapping's order.
    Homographies(Vec<&'a PreparedSubFrame>),
}

impl PreparedMapping {
    /// The mapping of the plane points with ordinate `y` (cm).
    pub fn row(&self, y: f64) -> RowMapping<'_> {
        match self {
            Self::Camera(c) => RowMapping::Camera(c),
            Self::Homographies(subs) => RowMapping::Homographies(
                subs.iter()
                    .filter(|s| y >= s.plane_bbox[1] && y <= s.plane_bbox[3])
                    .collect(),
            ),
        }
    }
}

impl RowMapping<'_> {
    /// Frame pixel that sees the plane point `q` of this row (its `y` is the row's);
    /// the same as [`PreparedMapping::plane_to_pixel`].
    pub fn plane_to_pixel(&self, q: Vec2) -> Option<Vec2> {
        match self {
            Self::Camera(c) => camera_pixel(c, q),
            Self::Homographies(subs) => average(
                subs.iter()
                    .filter(|s| q.x >= s.plane_bbox[0] && q.x <= s.plane_bbox[2])
                    .filter_map(|s| s.pixel(q)),
            ),
        }
    }
}

impl PreparedSubFrame {
    /// The pixel of this sub-frame that sees plane point `q`, if inside it.
    fn pixel(&self, q: Vec2) -> Option<Vec2> {
        self.inverse.apply(q).filter(|p| self.subframe.contains(*p))
    }
}

/// The pixel of camera `c` that sees plane point `q`, if inside the image.
fn camera_pixel(c: &Camera, q: Vec2) -> Option<Vec2> {
    c.project(Vec3::new(q.x, q.y, 0.0))
        .filter(|p| c.intrinsics.contains(*p))
}

fn average(it: impl Iterator<Item = Vec2>) -> Option<Vec2> {
    let (sum, n) = it.fold((Vec2::zeros(), 0usize), |(s, n), p| (s + p, n + 1));
    (n > 0).then(|| sum / n as f64)
}

impl RegisteredCapture {
    /// An empty capture over `region`.
    pub fn new(producer: impl Into<String>, region: Region, px_per_cm: f64) -> Self {
        Self {
            format: CAPTURE_FORMAT.into(),
            version: CAPTURE_VERSION,
            producer: producer.into(),
            units: "cm".into(),
            region,
            px_per_cm,
            light_intensity: None,
            sources: Vec::new(),
            frames: Vec::new(),
        }
    }

    /// Check internal consistency; `path` names the file in messages.
    pub fn validate(&self, path: &Path) -> Result<(), CoreError> {
        let bad = |m: String| Err(CoreError::format(path, m));
        if self.format != CAPTURE_FORMAT {
            return bad(format!(
                "format is {:?}, expected {CAPTURE_FORMAT:?}",
                self.format
            ));
        }
        if self.version != CAPTURE_VERSION {
            return bad(format!(
                "version {} is not supported (expected {CAPTURE_VERSION})",
                self.version
            ));
        }
        if self.units != "cm" {
            return bad(format!("units {:?}, expected \"cm\"", self.units));
        }
        self.region
            .validate()
            .map_err(|e| CoreError::format(path, e.to_string()))?;
        if !(self.px_per_cm > 0.0 && self.px_per_cm <= MAX_PX_PER_CM) {
            return bad(format!(
                "px_per_cm {} (expected pixels per cm in (0, {MAX_PX_PER_CM}], as the --px-per-cm flag)",
                self.px_per_cm
            ));
        }
        if self.region.width().max(self.region.height()) > MAX_REGION_CM {
            return bad(format!(
                "region {:.1} x {:.1} cm (expected at most {MAX_REGION_CM} cm on a side: a flat sample, not a room)",
                self.region.width(),
                self.region.height()
            ));
        }
        if let Some(i) = self.light_intensity {
            if !i.iter().all(|v| v.is_finite() && *v > 0.0) {
                return bad(format!(
                    "light_intensity {i:?} (expected three positive finite numbers, linear value * cm^2, or null when unknown)"
                ));
            }
        }
        if self.sources.is_empty() && !self.frames.is_empty() {
            return bad("no sources (expected at least one video or image folder)".into());
        }
        for (k, s) in self.sources.iter().enumerate() {
            if s.path.trim().is_empty() {
                return bad(format!("source {k} has an empty path (expected a video file or image folder relative to capture.json)"));
            }
        }
        let mut ids = std::collections::HashSet::new();
        for f in &self.frames {
            if !ids.insert(f.id) {
                return bad(format!("frame id {} appears twice", f.id));
            }
            let Some(src) = self.sources.get(f.source) else {
                return bad(format!(
                    "frame {} names source {} but there are {}",
                    f.id,
                    f.source,
                    self.sources.len()
                ));
            };
            match src.kind {
                SourceKind::Video if f.frame_index.is_none() => {
                    return bad(format!(
                        "frame {} comes from a video but has no frame_index",
                        f.id
                    ))
                }
                SourceKind::Images if f.image.is_none() => {
                    return bad(format!(
                        "frame {} comes from images but has no image name",
                        f.id
                    ))
                }
                _ => {}
            }
            if !(1..=MAX_FRAME_SIDE).contains(&f.width) || !(1..=MAX_FRAME_SIDE).contains(&f.height)
            {
                return bad(format!(
                    "frame {}: size {}x{} (expected 1 to {MAX_FRAME_SIDE} pixels a side)",
                    f.id, f.width, f.height
                ));
            }
            let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
            let mapping_finite = match &f.mapping {
                FrameMapping::Pinhole {
                    intrinsics,
                    distortion,
                    rotation,
                } => {
                    finite(&[
                        intrinsics.fx,
                        intrinsics.fy,
                        intrinsics.cx,
                        intrinsics.cy,
                        distortion.k1,
                        distortion.k2,
                    ]) && rotation.iter().all(|r| finite(r))
                        && intrinsics.fx > 0.0
                        && intrinsics.fy > 0.0
                }
                FrameMapping::Homographies { subframes } => {
                    !subframes.is_empty()
                        && subframes.iter().all(|s| {
                            finite(&s.rect) && s.plane_from_pixel.iter().all(|r| finite(r))
                        })
                }
            };
            if !finite(&f.camera_position) || !finite(&f.light_position) || !mapping_finite {
                return bad(format!(
                    "frame {}: a position or mapping is not a finite number (or a mapping is empty; expected finite cm positions, a camera with positive focal lengths or at least one sub-frame)",
                    f.id
                ));
            }
            if f.light_position[2] <= 0.0 || f.camera_position[2] <= 0.0 {
                return bad(format!(
                    "frame {}: camera z {} cm and light z {} cm must be above the plane (> 0)",
                    f.id, f.camera_position[2], f.light_position[2]
                ));
            }
            if let Some(g) = f.exposure_gain {
                if !(MIN_EXPOSURE_GAIN..=MAX_EXPOSURE_GAIN).contains(&g) {
                    return bad(format!(
                        "frame {}: exposure_gain {g} (expected a relative gain in [{MIN_EXPOSURE_GAIN}, {MAX_EXPOSURE_GAIN}], or none for fixed exposure)",
                        f.id
                    ));
                }
            }
            PreparedMapping::new(f).map_err(|e| CoreError::format(path, e.to_string()))?;
        }
        Ok(())
    }

    /// Read `capture.json` from a folder (or a direct path to the file) and validate it.
    pub fn load(path: &Path) -> Result<Self, CoreError> {
        let file = if path.is_dir() {
            path.join(CAPTURE_FILE)
        } else {
            path.to_path_buf()
        };
        if path.is_dir() && !file.exists() {
            // A refused alignment leaves only its record: say so rather than "no such
            // file".
            if let Some(v) = refused_alignment(path) {
                return Err(CoreError::format(
                    &file,
                    format!(
                        "there is no registered capture here: its alignment was refused ({}); what was tried is in {}",
                        v["error"].as_str().unwrap_or("no reason recorded"),
                        path.join(ALIGN_RECORD).display()
                    ),
                ));
            }
        }
        let cap: Self = crate::fsutil::read_json(&file)?;
        cap.validate(&file)?;
        Ok(cap)
    }

    /// Read a capture given as its folder or its `capture.json`, with the folder its
    /// relative source paths start from.
    pub fn load_with_folder(path: &Path) -> Result<(Self, std::path::PathBuf), CoreError> {
        let cap = Self::load(path)?;
        let dir = if path.is_dir() {
            path.to_path_buf()
        } else {
            path.parent().map(Path::to_path_buf).unwrap_or_default()
        };
        Ok((cap, dir))
    }

    /// Every file and folder this capture reads, for a capture whose `capture.json` is
    /// in `dir`: the file itself and each source (video file or image folder).
    pub fn input_paths(&self, dir: &Path) -> Vec<std::path::PathBuf> {
        let mut v = vec![dir.join(CAPTURE_FILE)];
        v.extend(self.sources.iter().map(|s| dir.join(&s.path)));
        v
    }

    /// Write `capture.json` into a folder, atomically.
    pub fn save(&self, dir: &Path) -> Result<(), CoreError> {
        let file = dir.join(CAPTURE_FILE);
        self.validate(&file)?;
        crate::fsutil::write_json(&file, self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::mat3_to_rows;

    fn frame(mapping: FrameMapping) -> Frame {
        Frame {
            id: 0,
            source: 0,
            frame_index: Some(0),
            image: None,
            time_s: Some(0.0),
            width: 640,
            height: 480,
            mapping,
            camera_position: [1.0, 2.0, 15.0],
            light_position: [2.4, 1.7, 15.0],
            exposure_gain: None,
        }
    }

    #[test]
    fn homography_mapping_agrees_with_camera_without_distortion() {
        let intr = Intrinsics::from_fov(640, 480, 70.0).unwrap();
        let pose = Pose::look_at(
            Vec3::new(1.0, 2.0, 15.0),
            Vec3::new(1.5, 2.0, 0.0),
            Vec3::y(),
        )
        .unwrap();
        let cam = Camera {
            intrinsics: intr,
            distortion: RadialDistortion::default(),
            pose,
        };
        let f = frame(FrameMapping::Pinhole {
            intrinsics: intr,
            distortion: RadialDistortion::default(),
            rotation: mat3_to_rows(&pose.rotation),
        });
        let pm = PreparedMapping::new(&f).unwrap();
        let src: Vec<Vec2> = [(0.0, 0.0), (639.0, 0.0), (639.0, 479.0), (0.0, 479.0)]
            .iter()
            .map(|&(x, y)| Vec2::new(x, y))
            .collect();
        let dst: Vec<Vec2> = src
            .iter()
            .map(|p| cam.pixel_to_plane(*p).unwrap())
            .collect();
        let h = Homography::from_correspondences(&src, &dst).unwrap();
        let hf = frame(FrameMapping::Homographies {
            subframes: vec![SubFrame {
                rect: [-0.5, -0.5, 639.5, 479.5],
                plane_from_pixel: mat3_to_rows(&h.0),
            }],
        });
        let hm = PreparedMapping::new(&hf).unwrap();
        for &(x, y) in &[(10.0, 20.0), (320.0, 240.0), (600.0, 400.0)] {
            let p = Vec2::new(x, y);
            let a = pm.pixel_to_plane(p).unwrap();
            let b = hm.pixel_to_plane(p).unwrap();
            assert!((a - b).norm() < 1e-6);
            let back = hm.plane_to_pixel(b).unwrap();
            assert!((back - p).norm() < 1e-6);
            let back = pm.plane_to_pixel(a).unwrap();
            assert!((back - p).norm() < 1e-6);
        }
        assert!(hm.plane_to_pixel(Vec2::new(100.0, 100.0)).is_none());
    }

    #[test]
    fn row_mapping_equals_the_pointwise_mapping() {
        // Four overlapping sub-frames with slightly different homographies (a
        // perspective term each), so that points see one, two or four of them.
        let subframes: Vec<SubFrame> = (0..4)
            .map(|i| {
                let (cx, cy) = (f64::from(i % 2), f64::from(i / 2));
                let e = 1e-4 * f64::from(i + 1);
                SubFrame {
                    rect: [
                        cx * 300.0 - 0.5,
                        cy * 220.0 - 0.5,
                        cx * 300.0 + 339.5,
                        cy * 220.0 + 259.5,
                    ],
                    plane_from_pixel: [
                        [0.01 + e, 0.001, -3.0],
                        [-0.0005, 0.01, -2.4 + e],
                        [e * 1e-3, -2e-6, 1.0],
                    ],
                }
            })
            .collect();
        let pm = PreparedMapping::new(&frame(FrameMapping::Homographies { subframes })).unwrap();
        let (mut seen, mut unseen) = (0, 0);
        for r in 0..60 {
            let y = -3.0 + 0.1 * f64::from(r);
            let row = pm.row(y);
            for c in 0..80 {
                let q = Vec2::new(-4.0 + 0.1 * f64::from(c), y);
                let (a, b) = (pm.plane_to_pixel(q), row.plane_to_pixel(q));
                assert_eq!(a, b, "{q:?}");
                if a.is_some() {
                    seen += 1;
                } else {
                    unseen += 1;
                }
            }
        }
        assert!(seen > 1000 && unseen > 100, "{seen} {unseen}");
    }

    #[test]
    fn validation_names_the_problem() {
        let mut cap = RegisteredCapture::new("test", Region::centred(4.0, 4.0), 10.0);
        cap.sources.push(Source {
            video: None,
            kind: SourceKind::Video,
            path: "v.mp4".into(),
            encoding: Encoding::Srgb,
            stream: 0,
        });
        let mut f = frame(FrameMapping::Homographies {
            subframes: vec![SubFrame {
                rect: [0.0, 0.0, 639.0, 479.0],
                plane_from_pixel: [[0.01, 0.0, 0.0], [0.0, 0.01, 0.0], [0.0, 0.0, 1.0]],
            }],
        });
        f.light_position[2] = -1.0;
        cap.frames.push(f);
        let err = cap
            .validate(Path::new("capture.json"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("light z -1"), "{err}");
    }
}
