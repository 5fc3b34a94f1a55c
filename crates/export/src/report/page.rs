//! The HTML page itself: escaping, embedded images as data URIs, sections, tables and
//! the per-frame chart.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use serde_json::Value;

use super::MAX_EMBED_SIDE;
use crate::ExportError;
use svbrdf_core::CoreError;

pub(super) fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

pub(super) fn base64(bytes: &[u8]) -> String {
    const T: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for c in bytes.chunks(3) {
        let n = (u32::from(c[0]) << 16)
            | (u32::from(*c.get(1).unwrap_or(&0)) << 8)
            | u32::from(*c.get(2).unwrap_or(&0));
        for k in 0..4 {
            if k <= c.len() {
                out.push(T[(n >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

/// A PNG as a data URI, shrunk to [`MAX_EMBED_SIDE`] when larger.
pub(super) fn data_uri(path: &Path) -> Result<String, ExportError> {
    let bytes = std::fs::read(path).map_err(|e| CoreError::io(path, e))?;
    let (w, h) = image::ImageReader::new(std::io::Cursor::new(&bytes))
        .with_guessed_format()
        .map_err(|e| CoreError::io(path, e))?
        .into_dimensions()
        .map_err(|e| CoreError::format(path, e.to_string()))?;
    let bytes = if w.max(h) > MAX_EMBED_SIDE {
        let img =
            image::load_from_memory(&bytes).map_err(|e| CoreError::format(path, e.to_string()))?;
        let small = img.thumbnail(MAX_EMBED_SIDE, MAX_EMBED_SIDE);
        let mut out = Vec::new();
        small
            .write_to(&mut std::io::Cursor::new(&mut out), image::ImageFormat::Png)
            .map_err(|e| CoreError::format(path, e.to_string()))?;
        out
    } else {
        bytes
    };
    Ok(format!("data:image/png;base64,{}", base64(&bytes)))
}

pub(super) fn read_json(path: &Path) -> Option<Value> {
    svbrdf_core::fsutil::read_json(path).ok()
}

/// Figures and images for the page, section by section.
pub(super) struct Page {
    pub(super) html: String,
    pub(super) images: usize,
}

impl Page {
    pub(super) fn section(&mut self, id: &str, title: &str, intro: &str) {
        let _ = write!(self.html, "<section id=\"{id}\"><h2>{}</h2>", escape(title));
        if !intro.is_empty() {
            let _ = write!(self.html, "<p>{intro}</p>");
        }
    }

    pub(super) fn end(&mut self) {
        self.html.push_str("</section>\n");
    }

    pub(super) fn figures(
        &mut self,
        items: &[(PathBuf, String)],
        wide: bool,
    ) -> Result<(), ExportError> {
        let class = if wide { "grid wide" } else { "grid" };
        let _ = write!(self.html, "<div class=\"{class}\">");
        for (p, caption) in items {
            if !p.exists() {
                continue;
            }
            let _ = write!(
                self.html,
                "<figure><img src=\"{}\" alt=\"{c}\"><figcaption>{c}</figcaption></figure>",
                data_uri(p)?,
                c = escape(caption)
            );
            self.images += 1;
        }
        self.html.push_str("</div>");
        Ok(())
    }

    pub(super) fn table(&mut self, rows: &[(String, String)]) {
        self.html.push_str("<table>");
        for (k, v) in rows {
            let _ = write!(
                self.html,
                "<tr><th>{}</th><td>{}</td></tr>",
                escape(k),
                escape(v)
            );
        }
        self.html.push_str("</table>");
    }
}

pub(super) fn num(v: &Value, digits: usize) -> String {
    v.as_f64()
        .map(|x| format!("{x:.digits$}"))
        .unwrap_or_else(|| v.to_string())
}

pub(super) fn timings(v: &Value) -> String {
    v.as_array()
        .map(|a| {
            a.iter()
                .map(|t| format!("{} {} s", t[0].as_str().unwrap_or("?"), num(&t[1], 1)))
                .collect::<Vec<_>>()
                .join(", ")
        })
        .unwrap_or_default()
}

/// Per-frame re-rendering error as an inline SVG bar chart.
pub(super) fn frame_chart(frames: &[Value]) -> String {
    let (w, h) = (720.0, 160.0);
    let vals: Vec<f64> = frames
        .iter()
        .map(|f| f["relative"].as_f64().unwrap_or(0.0))
        .collect();
    let max = vals.iter().copied().fold(1e-9, f64::max);
    let bw = w / vals.len().max(1) as f64;
    let mut s = format!(
        "<svg class=\"chart\" viewBox=\"0 0 {w} {}\" role=\"img\" aria-label=\"per-frame error\">",
        h + 20.0
    );
    for (i, v) in vals.iter().enumerate() {
        let bh = h * v / max;
        let _ = write!(
            s,
            "<rect x=\"{:.1}\" y=\"{:.1}\" width=\"{:.1}\" height=\"{bh:.1}\"><title>frame {}: {:.1}%</title></rect>",
            i as f64 * bw,
            h - bh,
            (bw - 1.0).max(0.5),
            frames[i]["frame"],
            100.0 * v
        );
    }
    let _ = write!(
        s,
        "<text x=\"0\" y=\"{}\">0</text><text x=\"{w}\" y=\"12\" text-anchor=\"end\">max {:.1}% of the frame's mean</text></svg>",
        h + 16.0,
        100.0 * max
    );
    s
}
