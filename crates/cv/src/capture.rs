//! Decoding the frames of a registered capture for the appearance stage. Video sources
//! are decoded as one forward stream each (frames in index order) on a thread of their
//! own, one frame ahead of the consumer, so decoding overlaps with the consumer's
//! work; image sources are read one file at a time. 8-bit SDR video frames stay 8-bit
//! sRGB ([`FrameImage::Srgb8`]; the consumer linearises per sample); 10-bit and HDR
//! frames arrive linear ([`FrameImage::Linear`]).

use std::path::Path;
use std::sync::mpsc;

use svbrdf_core::capture::{RegisteredCapture, SourceKind};
use svbrdf_core::image::FrameImage;
use svbrdf_core::maps::{read_image_linear, Encoding};

use crate::video::VideoReader;
use crate::CvError;

/// Decode the given frames (indices into `capture.frames`, sorted by frame index) of one
/// video, sending each as it is ready.
fn decode_video(
    capture: &RegisteredCapture,
    path: &Path,
    encoding: Encoding,
    frames: &[usize],
    tx: &mpsc::SyncSender<Result<(usize, FrameImage), CvError>>,
) {
    let run = || -> Result<(), CvError> {
        let mut reader = VideoReader::open(path)?;
        for &k in frames {
            let want = capture.frames[k].frame_index.unwrap_or(0);
            while reader.next_index() < want {
                if !reader.skip()? {
                    break;
                }
            }
            let idx = reader.next_index();
            let Some(img) = reader.read_image()? else {
                return Err(CvError::File {
                    path: path.into(),
                    message: format!(
                        "the capture names frame {want} but the video ends at frame {idx}"
                    ),
                });
            };
            let frame = match (encoding, img) {
                (Encoding::Linear, FrameImage::Srgb8(img)) => {
                    FrameImage::Linear(svbrdf_core::image::ImageF32 {
                        width: img.width,
                        height: img.height,
                        channels: img.channels,
                        data: img.data.iter().map(|&v| f32::from(v) / 255.0).collect(),
                    })
                }
                // 10-bit and HDR video: linear floats from FFmpeg's libraries.
                (_, img) => img,
            };
            if tx.send(Ok((k, frame))).is_err() {
                // The consumer stopped (it failed); nothing more to do.
                return Ok(());
            }
        }
        Ok(())
    };
    if let Err(e) = run() {
        let _ = tx.send(Err(e));
    }
}

/// Call `sink(k, image)` for every frame `k` of `capture.frames` (in decode order, not
/// necessarily `k` order). `dir` is the folder holding `capture.json` (source paths are
/// relative to it). Images from video and 8-bit files arrive as sRGB codes or linear
/// floats as the source's `encoding` says.
pub fn decode_frames<E: From<CvError>>(
    capture: &RegisteredCapture,
    dir: &Path,
    sink: &mut dyn FnMut(usize, FrameImage) -> Result<(), E>,
) -> Result<(), E> {
    for (s, source) in capture.sources.iter().enumerate() {
        let path = dir.join(&source.path);
        let mut frames: Vec<usize> = (0..capture.frames.len())
            .filter(|&k| capture.frames[k].source == s)
            .collect();
        if frames.is_empty() {
            continue;
        }
        match source.kind {
            SourceKind::Video => {
                frames.sort_by_key(|&k| capture.frames[k].frame_index.unwrap_or(0));
                let (tx, rx) = mpsc::sync_channel(1);
                std::thread::scope(|scope| -> Result<(), E> {
                    let path = &path;
                    let frames = &frames;
                    scope.spawn(move || decode_video(capture, path, source.encoding, frames, &tx));
                    for msg in rx {
                        let (k, img) = msg?;
                        sink(k, img)?;
                    }
                    Ok(())
                })?;
            }
            SourceKind::Images => {
                for k in frames {
                    let name = capture.frames[k].image.clone().unwrap_or_default();
                    let file = path.join(&name);
                    let exr = file
                        .extension()
                        .is_some_and(|e| e.eq_ignore_ascii_case("exr"));
                    let img = if exr || source.encoding != Encoding::Srgb {
                        FrameImage::Linear(read_image_linear(&file, source.encoding).map_err(
                            |e| CvError::File {
                                path: file.clone(),
                                message: e.to_string(),
                            },
                        )?)
                    } else {
                        // OpenCV applies the EXIF orientation, as alignment saw the photo.
                        FrameImage::Srgb8(crate::read_image(&file)?)
                    };
                    sink(k, img)?;
                }
            }
        }
    }
    Ok(())
}
