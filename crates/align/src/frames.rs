//! Streaming decode of the kept frames and per-frame work: blur metric (eq. 1),
//! markers, coarse and fine SIFT features. Only features and a small thumbnail stay in
//! memory, so memory grows with the number of kept frames, not with video length.

use std::path::Path;
use std::sync::Arc;

use rayon::prelude::*;
use svbrdf_core::geometry::Vec2;
use svbrdf_core::image::ImageU8;
use svbrdf_cv::aruco::{detect_markers, Dictionary};
use svbrdf_cv::features::{downscaled, sift, Features};
use svbrdf_cv::video::{luma_frame_of, LumaFrame, VideoReader};

/// Fewest frames a flash video may hold.
pub const MIN_VIDEO_FRAMES: u64 = 10;

/// Long side of the thumbnails kept for the panorama, pixels.
pub(crate) const THUMB_LONG: u32 = 480;

use crate::blur::blur_metric;
use crate::config::{AlignConfig, FineMethod};
use crate::patch::Grey;
use crate::reference::MarkerObservation;
use crate::{AlignError, Progress};

/// Everything kept about one decoded frame.
#[derive(Debug, Clone)]
pub struct FrameData {
    /// Frame number in the video.
    pub index: u64,
    /// Camera stream: 0 the flash video, 1 the second (no-flash) video.
    pub stream: u32,
    /// File name inside the photo folder, for still photos.
    pub file: Option<String>,
    /// Time on the flash camera's clock, seconds.
    pub time_s: f64,
    /// Full-resolution width.
    pub width: u32,
    /// Full-resolution height.
    pub height: u32,
    /// Eq. (1).
    pub blur: f64,
    /// Markers, full-resolution pixels.
    pub markers: Vec<MarkerObservation>,
    /// Coarse features, coordinates in full-resolution pixels.
    pub coarse: Features,
    /// Fine features, coordinates in full-resolution pixels (`FineMethod::Sift`).
    pub fine: Features,
    /// Luminance at the fine scale for patch refinement (`FineMethod::Patch`); shared,
    /// since frames are cloned while the connected set is chosen.
    pub grey: Option<Arc<Grey>>,
    /// Small image for the panorama (long side <= 480).
    pub thumb: ImageU8,
}

#[cfg(test)]
impl FrameData {
    /// A frame for unit tests: its patch image and coarse features, the rest empty.
    pub(crate) fn for_test(grey: Grey, coarse: Features) -> Self {
        Self {
            index: 0,
            stream: 0,
            file: None,
            time_s: 0.0,
            width: grey.width as u32,
            height: grey.height as u32,
            blur: 0.0,
            markers: Vec::new(),
            coarse,
            fine: Features::default(),
            grey: Some(Arc::new(grey)),
            thumb: ImageU8::new(1, 1, 3),
        }
    }
}

/// Map feature coordinates from an image scaled by `s` back to full resolution.
fn unscale(mut f: Features, s: f64) -> Features {
    for p in &mut f.points {
        p[0] = ((f64::from(p[0]) + 0.5) / s - 0.5) as f32;
        p[1] = ((f64::from(p[1]) + 0.5) / s - 0.5) as f32;
    }
    f
}

/// A frame reduced to the coarse scale (long side `coarse_long_side`).
pub(crate) fn coarse_image(luma: &ImageU8, cfg: &AlignConfig) -> Result<ImageU8, AlignError> {
    let long = luma.width.max(luma.height) as f64;
    let cs = (f64::from(cfg.coarse_long_side) / long).min(1.0);
    Ok(downscaled(luma, cs)?)
}

/// Eq. (1) of an 8-bit grey image.
pub(crate) fn blur_of(img: &ImageU8) -> f64 {
    let grey: Vec<f32> = img.data.iter().map(|&v| f32::from(v) / 255.0).collect();
    blur_metric(&grey, img.width, img.height)
}

/// The blur metric (eq. 1) of a frame at the coarse scale, and that coarse image.
fn coarse_blur(luma: &ImageU8, cfg: &AlignConfig) -> Result<(ImageU8, f64), AlignError> {
    let coarse_img = coarse_image(luma, cfg)?;
    let blur = blur_of(&coarse_img);
    Ok((coarse_img, blur))
}

/// The per-frame work; `coarse` is the frame's coarse image and blur metric when
/// already computed (by [`pick_sharpest`]).
pub(crate) fn process(
    frame: LumaFrame,
    coarse: Option<(ImageU8, f64)>,
    index: u64,
    fps: f64,
    cfg: &AlignConfig,
    dict: Dictionary,
) -> Result<FrameData, AlignError> {
    let LumaFrame { luma, thumb } = frame;
    let (width, height) = (luma.width, luma.height);
    let long = width.max(height) as f64;
    let cs = (f64::from(cfg.coarse_long_side) / long).min(1.0);
    let fs = (f64::from(cfg.fine_long_side) / long).min(1.0);
    // Everything but the thumbnail works on luminance (converted once, at full
    // resolution, while decoding), with area-averaged grey images: a third of the data
    // of RGB.
    let (coarse_img, blur) = match coarse {
        Some(c) => c,
        None => coarse_blur(&luma, cfg)?,
    };
    // Markers are found in the coarse image (a quarter of the pixels of the 1920 px
    // image) and their corners located at up to 1920 px, large enough for sub-pixel
    // corners.
    let ms = (1920.0 / long).min(1.0).max(cs);
    let marker_img = downscaled(&luma, ms)?;
    let lum = crate::corners::Luminance::new(&marker_img);
    let cells = dict.cells();
    let to_ms = |c: [f64; 2]| Vec2::new((c[0] + 0.5) * ms / cs - 0.5, (c[1] + 0.5) * ms / cs - 0.5);
    let markers = detect_markers(&coarse_img, dict)?
        .into_iter()
        .map(|m| {
            let c = crate::corners::refine_corners(&lum, &m.corners.map(to_ms), cells);
            MarkerObservation {
                id: m.id,
                corners: c.map(|p| Vec2::new((p.x + 0.5) / ms - 0.5, (p.y + 0.5) / ms - 0.5)),
            }
        })
        .collect();
    let exclude = |w: usize, h: usize| {
        let l = w.max(h) as f64;
        Some([
            0.5 * (w as f64 - 1.0),
            0.5 * (h as f64 - 1.0),
            cfg.highlight_radius * l,
        ])
    };
    let coarse = unscale(
        sift(
            &coarse_img,
            cfg.coarse_features,
            cfg.sift_contrast,
            exclude(coarse_img.width, coarse_img.height),
        )?,
        cs,
    );
    let (fine, grey) = match cfg.fine_method {
        FineMethod::Sift => {
            let fine_img = downscaled(&luma, fs)?;
            (
                unscale(
                    sift(
                        &fine_img,
                        cfg.fine_features,
                        cfg.sift_contrast,
                        exclude(fine_img.width, fine_img.height),
                    )?,
                    fs,
                ),
                None,
            )
        }
        FineMethod::Patch => {
            let fine_img = if fs < 1.0 {
                downscaled(&luma, fs)?
            } else {
                luma
            };
            (
                Features::default(),
                Some(Arc::new(Grey {
                    width: fine_img.width,
                    height: fine_img.height,
                    data: fine_img.data,
                })),
            )
        }
    };
    Ok(FrameData {
        index,
        stream: 0,
        file: None,
        time_s: index as f64 / fps.max(1e-9),
        width: width as u32,
        height: height as u32,
        blur,
        markers,
        coarse,
        fine,
        grey,
        thumb,
    })
}

/// Decode every `frame_step`-th frame on one thread while the others process the
/// previous batch in parallel (decoding 4K H.264 is a large share of the work).
/// Returns the frames and how the stream was decoded.
pub fn decode_frames(
    video: &Path,
    cfg: &AlignConfig,
    dict: Dictionary,
    progress: &dyn Progress,
) -> Result<(Vec<FrameData>, crate::VideoDecoding), AlignError> {
    let mut reader = VideoReader::open(video)?;
    if let Some(n) = reader.probe().expected_frames() {
        if n < MIN_VIDEO_FRAMES {
            return Err(AlignError::Video(format!(
                "{}: the video holds {n} frame{} (expected at least {MIN_VIDEO_FRAMES}: a 15-30 s sweep is hundreds; for still photos use `align --photos FOLDER`)",
                video.display(),
                if n == 1 { "" } else { "s" }
            )));
        }
    }
    let info = reader.info();
    let decoding = crate::VideoDecoding::of(reader.probe(), &reader.decoding());
    let step = u64::from(cfg.camera.frame_step);
    // Windows of 2 * radius + 1 frames centred on every `step`-th frame (the first
    // window starts at frame 0).
    let radius = u64::from(cfg.sharpest_within).min((step - 1) / 2);
    let offset = move |idx: u64| (idx + radius) % step;
    let window_of = move |idx: u64| (idx + radius) / step;
    progress.stage("decode + features", info.frame_count.div_ceil(step));
    let batch_size = 2 * rayon::current_num_threads().max(1);
    let (tx, rx) =
        std::sync::mpsc::sync_channel::<Result<(u64, LumaFrame), AlignError>>(batch_size);
    let mut out = Vec::new();
    // Each decoded frame's time from the stream (variable frame rates keep theirs).
    let times = std::sync::Mutex::new(std::collections::HashMap::<u64, f64>::new());
    let times_ref = &times;
    std::thread::scope(|scope| -> Result<(), AlignError> {
        scope.spawn(move || loop {
            let idx = reader.next_index();
            // The frames within `radius` of every `step`-th frame are decoded, and the
            // sharpest of each such window is used.
            let frame = if offset(idx) <= 2 * radius {
                reader.read_luma(THUMB_LONG).map_err(AlignError::from)
            } else {
                match reader.skip() {
                    Ok(true) => continue,
                    Ok(false) => Ok(None),
                    Err(e) => Err(e.into()),
                }
            };
            match frame {
                Ok(Some(f)) => {
                    if let Ok(mut t) = times_ref.lock() {
                        t.insert(idx, reader.time_s());
                    }
                    if tx.send(Ok((idx, f))).is_err() {
                        return;
                    }
                }
                Ok(None) => {
                    // The end: refuse a video that stopped decoding early.
                    if let Err(e) = reader.check_complete() {
                        let _ = tx.send(Err(e.into()));
                    }
                    return;
                }
                Err(e) => {
                    let _ = tx.send(Err(e));
                    return;
                }
            }
        });
        // Owned here so that an early error drops it and unblocks the decoder thread.
        let rx = rx;
        // Windows of `step` consecutive frames; each gives one frame, its sharpest.
        let mut batch: Vec<Vec<(u64, LumaFrame)>> = Vec::with_capacity(batch_size);
        let flush = |batch: &mut Vec<Vec<(u64, LumaFrame)>>,
                     out: &mut Vec<FrameData>|
         -> Result<(), AlignError> {
            let n = batch.len() as u64;
            let chosen: Vec<Chosen> = std::mem::take(batch)
                .into_par_iter()
                .map(|window| pick_sharpest(window, cfg))
                .collect::<Result<Vec<_>, AlignError>>()?
                .into_iter()
                .flatten()
                .collect();
            let processed: Vec<Result<FrameData, AlignError>> = chosen
                .into_par_iter()
                .map(|(i, f, coarse)| process(f, Some(coarse), i, info.fps, cfg, dict))
                .collect();
            for p in processed {
                out.push(p?);
            }
            progress.advance(n);
            Ok(())
        };
        let mut window: Vec<(u64, LumaFrame)> = Vec::new();
        for item in rx.iter() {
            let (idx, f) = item?;
            if window
                .first()
                .is_some_and(|(w, _)| window_of(*w) != window_of(idx))
            {
                batch.push(std::mem::take(&mut window));
                if batch.len() == batch_size {
                    flush(&mut batch, &mut out)?;
                }
            }
            window.push((idx, f));
        }
        if !window.is_empty() {
            batch.push(window);
        }
        if !batch.is_empty() {
            flush(&mut batch, &mut out)?;
        }
        Ok(())
    })?;
    progress.finish();
    if let Ok(t) = times.lock() {
        for f in &mut out {
            if let Some(time) = t.get(&f.index) {
                f.time_s = *time;
            }
        }
    }
    if out.is_empty() {
        return Err(AlignError::Video(format!(
            "{}: no frames could be decoded",
            video.display()
        )));
    }
    Ok((out, decoding))
}

/// A frame chosen from its window, with its coarse image and blur metric.
type Chosen = (u64, LumaFrame, (ImageU8, f64));

/// The sharpest frame of a window (highest eq. 1), or `None` for an empty window.
/// Motion blur comes from a jerk of the hand that lasts a frame or two; the frames of
/// one window show nearly the same content, so eq. 1 compares them fairly.
fn pick_sharpest(
    window: Vec<(u64, LumaFrame)>,
    cfg: &AlignConfig,
) -> Result<Option<Chosen>, AlignError> {
    let mut best: Option<Chosen> = None;
    for (i, f) in window {
        let coarse = coarse_blur(&f.luma, cfg)?;
        if best.as_ref().is_none_or(|b| coarse.1 > b.2 .1) {
            best = Some((i, f, coarse));
        }
    }
    Ok(best)
}

/// Read every JPEG/PNG in `dir` (sorted by name; OpenCV applies EXIF orientation) and
/// do the per-frame work on each. All photos must have one size, since they share one
/// camera description.
pub fn read_photos(
    dir: &Path,
    cfg: &AlignConfig,
    dict: Dictionary,
    progress: &dyn Progress,
) -> Result<Vec<FrameData>, AlignError> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .map_err(|e| {
            AlignError::Video(format!(
                "{}: cannot read the photo folder ({e})",
                dir.display()
            ))
        })?
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| {
            let l = n.to_ascii_lowercase();
            l.ends_with(".jpg") || l.ends_with(".jpeg") || l.ends_with(".png")
        })
        .collect();
    names.sort();
    if names.len() < 2 {
        return Err(AlignError::Video(format!(
            "{}: {} photo(s) (JPEG or PNG) found, expected at least 2",
            dir.display(),
            names.len()
        )));
    }
    progress.stage("photos: markers + features", names.len() as u64);
    let out: Vec<Result<FrameData, AlignError>> = names
        .par_iter()
        .enumerate()
        .map(|(k, name)| {
            let img = svbrdf_cv::read_image(&dir.join(name))?;
            let frame = luma_frame_of(&img, THUMB_LONG)?;
            drop(img);
            let mut f = process(frame, None, k as u64, 1.0, cfg, dict)?;
            f.file = Some(name.clone());
            progress.advance(1);
            Ok(f)
        })
        .collect();
    progress.finish();
    let out: Vec<FrameData> = out.into_iter().collect::<Result<_, _>>()?;
    let (w, h) = (out[0].width, out[0].height);
    if let Some(f) = out.iter().find(|f| (f.width, f.height) != (w, h)) {
        return Err(AlignError::Video(format!(
            "{}: {}x{} pixels, but {} is {w}x{h} (expected one size: the photos share one camera description)",
            dir.join(f.file.as_deref().unwrap_or("?")).display(),
            f.width,
            f.height,
            out[0].file.as_deref().unwrap_or("?")
        )));
    }
    Ok(out)
}
