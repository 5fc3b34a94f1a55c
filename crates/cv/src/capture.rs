//! Decoding the frames of a registered capture as linear RGB, for the appearance stage.
//! Video sources are decoded as one forward stream each (frames in index order);
//! image sources are read one file at a time. One frame is in flight at a time.

use std::path::Path;

use svbrdf_core::capture::{RegisteredCapture, SourceKind};
use svbrdf_core::color::srgb8_to_linear_table;
use svbrdf_core::image::{ImageF32, ImageU8};
use svbrdf_core::maps::{read_image_linear, Encoding};

use crate::video::VideoReader;
use crate::CvError;

fn to_linear(img: &ImageU8, encoding: Encoding, lut: &[f32; 256]) -> ImageF32 {
    let data = img
        .data
        .iter()
        .map(|&v| match encoding {
            Encoding::Srgb => lut[usize::from(v)],
            Encoding::Linear => f32::from(v) / 255.0,
        })
        .collect();
    ImageF32 {
        width: img.width,
        height: img.height,
        channels: img.channels,
        data,
    }
}

/// Call `sink(k, image)` for every frame `k` of `capture.frames` (in decode order, not
/// necessarily `k` order), with the frame's pixels as linear RGB. `dir` is the folder
/// holding `capture.json` (source paths are relative to it).
pub fn decode_frames<E: From<CvError>>(
    capture: &RegisteredCapture,
    dir: &Path,
    sink: &mut dyn FnMut(usize, ImageF32) -> Result<(), E>,
) -> Result<(), E> {
    let lut = srgb8_to_linear_table();
    for (s, source) in capture.sources.iter().enumerate() {
        let path = dir.join(&source.path);
        let mut frames: Vec<usize> = (0..capture.frames.len())
            .filter(|&k| capture.frames[k].source == s)
            .collect();
        match source.kind {
            SourceKind::Video => {
                frames.sort_by_key(|&k| capture.frames[k].frame_index.unwrap_or(0));
                if frames.is_empty() {
                    continue;
                }
                let mut reader = VideoReader::open(&path)?;
                for k in frames {
                    let want = capture.frames[k].frame_index.unwrap_or(0);
                    while reader.next_index() < want {
                        if !reader.skip()? {
                            break;
                        }
                    }
                    let idx = reader.next_index();
                    let Some(img) = reader.read()? else {
                        return Err(CvError::File {
                            path: path.clone(),
                            message: format!(
                                "the capture names frame {want} but the video ends at frame {idx}"
                            ),
                        }
                        .into());
                    };
                    sink(k, to_linear(&img, source.encoding, &lut))?;
                }
            }
            SourceKind::Images => {
                for k in frames {
                    let name = capture.frames[k].image.clone().unwrap_or_default();
                    let file = path.join(&name);
                    let img =
                        read_image_linear(&file, source.encoding).map_err(|e| CvError::File {
                            path: file.clone(),
                            message: e.to_string(),
                        })?;
                    sink(k, img)?;
                }
            }
        }
    }
    Ok(())
}
