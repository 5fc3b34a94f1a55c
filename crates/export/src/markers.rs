//! The capture kit's printable marker sheet: four markers at their exact physical size
//! on an A4 page, ids and placement printed beside them, dashed cut lines, and a 5 cm
//! scale bar to check that the printer did not rescale. As SVG (millimetre units, the
//! file to print) and as a 300 dpi PNG of the same page.
use std::fmt::Write as _;

use svbrdf_core::image::ImageU8;
use svbrdf_core::CoreError;

/// One marker's printed pattern: `cells x cells`, row-major from its top-left, `true` =
/// white (the one-cell black border included).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MarkerCells {
    /// Marker id in the dictionary.
    pub id: i32,
    /// Cells per side, border included.
    pub cells: usize,
    /// Cell colours.
    pub white: Vec<bool>,
}

/// Page size, mm (A4 portrait).
pub const PAGE_MM: (f64, f64) = (210.0, 297.0);
/// Raster resolution of the PNG, dots per inch.
pub const DPI: f64 = 300.0;
/// Length of the scale bar, mm.
pub const SCALE_BAR_MM: f64 = 50.0;

const PLACES: [&str; 4] = [
    "top-left corner",
    "top-right corner",
    "bottom-right corner",
    "bottom-left corner",
];

/// Where marker `k` (0..4) is centred on the page, mm.
fn centre(k: usize) -> (f64, f64) {
    let x = if k == 0 || k == 3 { 60.0 } else { 150.0 };
    let y = if k < 2 { 85.0 } else { 175.0 };
    (x, y)
}

/// Check the inputs of the sheet.
fn check(markers: &[MarkerCells], size_mm: f64) -> Result<(), CoreError> {
    if markers.len() != 4 {
        return Err(CoreError::invalid("marker count", markers.len(), "4"));
    }
    if !(5.0..=60.0).contains(&size_mm) {
        return Err(CoreError::invalid(
            "marker size",
            format!("{} cm", size_mm / 10.0),
            "0.5 to 6 cm (four markers must fit on an A4 page)",
        ));
    }
    for m in markers {
        if m.cells < 3 || m.white.len() != m.cells * m.cells {
            return Err(CoreError::invalid(
                "marker pattern",
                format!("{} cells for id {}", m.white.len(), m.id),
                "cells x cells values",
            ));
        }
    }
    Ok(())
}

/// The sheet as SVG (units: mm; print at 100% / "actual size").
pub fn svg(markers: &[MarkerCells], size_mm: f64, dictionary: &str) -> Result<String, CoreError> {
    check(markers, size_mm)?;
    let (w, h) = PAGE_MM;
    let mut s = String::new();
    let _ = writeln!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}mm" height="{h}mm" viewBox="0 0 {w} {h}" font-family="sans-serif">"#
    );
    let _ = writeln!(s, r#"<rect width="{w}" height="{h}" fill="white"/>"#);
    let _ = writeln!(
        s,
        r#"<text x="20" y="20" font-size="6">svbrdf capture markers: {dictionary}, {:.1} cm</text>"#,
        size_mm / 10.0
    );
    let _ = writeln!(
        s,
        r#"<text x="20" y="28" font-size="3.6">Print at 100% ("actual size"), then check that the bar below measures exactly {SCALE_BAR_MM:.0} mm. Cut along the dashed lines.</text>"#
    );
    let _ = writeln!(
        s,
        r#"<text x="20" y="38" font-size="3.6">Lay the markers outside the four corners of the material, their inner corners</text>"#
    );
    let _ = writeln!(
        s,
        r#"<text x="20" y="43" font-size="3.6">on its corners, every marker's top edge towards the top of the reference photo.</text>"#
    );
    for (k, m) in markers.iter().enumerate() {
        let (cx, cy) = centre(k);
        let cell = size_mm / m.cells as f64;
        let (x0, y0) = (cx - 0.5 * size_mm, cy - 0.5 * size_mm);
        // Quiet zone of one cell, then the cut line.
        let q = cell;
        let _ = writeln!(
            s,
            r#"<rect x="{:.4}" y="{:.4}" width="{:.4}" height="{:.4}" fill="none" stroke="gray" stroke-width="0.2" stroke-dasharray="1.5,1"/>"#,
            x0 - q,
            y0 - q,
            size_mm + 2.0 * q,
            size_mm + 2.0 * q
        );
        let _ = write!(s, r#"<g fill="black" shape-rendering="crispEdges">"#);
        for r in 0..m.cells {
            for c in 0..m.cells {
                if !m.white[r * m.cells + c] {
                    let _ = write!(
                        s,
                        r#"<rect x="{:.4}" y="{:.4}" width="{:.4}" height="{:.4}"/>"#,
                        x0 + c as f64 * cell,
                        y0 + r as f64 * cell,
                        cell + 0.01,
                        cell + 0.01
                    );
                }
            }
        }
        let _ = writeln!(s, "</g>");
        let _ = writeln!(
            s,
            r#"<text x="{cx:.3}" y="{:.3}" font-size="4" text-anchor="middle">id {} ({})</text>"#,
            y0 + size_mm + q + 7.0,
            m.id,
            PLACES[k]
        );
        let _ = writeln!(
            s,
            r#"<text x="{cx:.3}" y="{:.3}" font-size="3" text-anchor="middle">top</text>"#,
            y0 - q - 1.5
        );
    }
    let (bx, by) = (80.0, 245.0);
    let _ = writeln!(
        s,
        r#"<rect x="{bx}" y="{by}" width="{SCALE_BAR_MM}" height="2" fill="black"/>"#
    );
    for t in 0..=5 {
        let x = bx + f64::from(t) * 10.0;
        let a = (x - 0.15).clamp(bx, bx + SCALE_BAR_MM - 0.3);
        let _ = writeln!(
            s,
            r#"<rect x="{a:.3}" y="{}" width="0.3" height="5" fill="black"/>"#,
            by - 1.5
        );
    }
    let _ = writeln!(
        s,
        r#"<text x="{:.1}" y="{}" font-size="4" text-anchor="middle">{SCALE_BAR_MM:.0} mm = 5 cm</text>"#,
        bx + 0.5 * SCALE_BAR_MM,
        by + 10.0
    );
    s.push_str("</svg>\n");
    Ok(s)
}

/// 5x7 glyphs for the PNG's labels (the SVG uses real text).
fn glyph(c: char) -> Option<[u8; 7]> {
    Some(match c {
        '0' => [0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E],
        '1' => [0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E],
        '2' => [0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F],
        '3' => [0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E],
        '4' => [0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02],
        '5' => [0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E],
        '6' => [0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E],
        '7' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08],
        '8' => [0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E],
        '9' => [0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C],
        'C' => [0x0E, 0x11, 0x10, 0x10, 0x10, 0x11, 0x0E],
        'D' => [0x1C, 0x12, 0x11, 0x11, 0x11, 0x12, 0x1C],
        'I' => [0x0E, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E],
        'M' => [0x11, 0x1B, 0x15, 0x15, 0x11, 0x11, 0x11],
        ' ' => [0; 7],
        _ => return None,
    })
}

/// The same sheet rasterised at [`DPI`] (greyscale, 1 channel).
pub fn raster(markers: &[MarkerCells], size_mm: f64) -> Result<ImageU8, CoreError> {
    check(markers, size_mm)?;
    let px = |mm: f64| mm / 25.4 * DPI;
    let (w, h) = (
        px(PAGE_MM.0).round() as usize,
        px(PAGE_MM.1).round() as usize,
    );
    let mut img = ImageU8::new(w, h, 1);
    img.data.fill(255);
    // Fill [x0, x1) x [y0, y1) in mm with `v`; pixel (i, j) covers [i, i+1) x [j, j+1).
    let mut fill = |x0: f64, y0: f64, x1: f64, y1: f64, v: u8| {
        let (i0, i1) = (px(x0).round() as usize, (px(x1).round() as usize).min(w));
        let (j0, j1) = (px(y0).round() as usize, (px(y1).round() as usize).min(h));
        for j in j0..j1 {
            img.data[j * w + i0.min(i1)..j * w + i1].fill(v);
        }
    };
    let text = |fill: &mut dyn FnMut(f64, f64, f64, f64, u8), x: f64, y: f64, t: &str, dot: f64| {
        let mut cx = x;
        for ch in t.chars() {
            if let Some(g) = glyph(ch) {
                for (r, row) in g.iter().enumerate() {
                    for c in 0..5 {
                        if row & (0x10 >> c) != 0 {
                            let (gx, gy) = (cx + c as f64 * dot, y + r as f64 * dot);
                            fill(gx, gy, gx + dot, gy + dot, 0);
                        }
                    }
                }
            }
            cx += 6.0 * dot;
        }
    };
    for (k, m) in markers.iter().enumerate() {
        let (cx, cy) = centre(k);
        let cell = size_mm / m.cells as f64;
        let (x0, y0) = (cx - 0.5 * size_mm, cy - 0.5 * size_mm);
        let q = cell;
        // Dashed cut line.
        let (l, t, r, b) = (x0 - q, y0 - q, x0 + size_mm + q, y0 + size_mm + q);
        let mut d = 0.0;
        while d < r - l {
            let e = (d + 1.5).min(r - l);
            fill(l + d, t, l + e, t + 0.2, 136);
            fill(l + d, b - 0.2, l + e, b, 136);
            d += 2.5;
        }
        let mut d = 0.0;
        while d < b - t {
            let e = (d + 1.5).min(b - t);
            fill(l, t + d, l + 0.2, t + e, 136);
            fill(r - 0.2, t + d, r, t + e, 136);
            d += 2.5;
        }
        for rr in 0..m.cells {
            for c in 0..m.cells {
                if !m.white[rr * m.cells + c] {
                    let (a, bb) = (x0 + c as f64 * cell, y0 + rr as f64 * cell);
                    fill(a, bb, a + cell, bb + cell, 0);
                }
            }
        }
        let label = format!("ID {}", m.id);
        text(
            &mut fill,
            cx - 3.0 * 0.6 * label.len() as f64,
            b + 3.0,
            &label,
            0.6,
        );
    }
    let (bx, by) = (80.0, 245.0);
    fill(bx, by, bx + SCALE_BAR_MM, by + 2.0, 0);
    for t in 0..=5 {
        let x = bx + f64::from(t) * 10.0;
        // End ticks stay inside the bar so that it measures exactly 50 mm.
        let (a, b) = ((x - 0.15).max(bx), (x + 0.15).min(bx + SCALE_BAR_MM));
        fill(a, by - 1.5, b, by + 3.5, 0);
    }
    text(&mut fill, bx + 14.0, by + 6.0, "5 CM", 0.8);
    Ok(img)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fake() -> Vec<MarkerCells> {
        (0..4)
            .map(|id| MarkerCells {
                id,
                cells: 8,
                white: (0..64)
                    .map(|i| {
                        let (r, c) = (i / 8, i % 8);
                        r > 0 && r < 7 && c > 0 && c < 7 && (r + c + id as usize).is_multiple_of(2)
                    })
                    .collect(),
            })
            .collect()
    }

    #[test]
    fn raster_markers_have_their_physical_size_at_300_dpi() {
        let img = raster(&fake(), 16.0).expect("raster");
        assert_eq!((img.width, img.height), (2480, 3508));
        // Marker 0 spans 16 mm = 189 px: count black pixels along its top border row.
        let (cx, cy) = centre(0);
        let y = ((cy - 8.0 + 1.0) / 25.4 * DPI) as usize;
        let row = &img.data[y * img.width..(y + 1) * img.width];
        let x_lo = ((cx - 20.0) / 25.4 * DPI) as usize;
        let x_hi = ((cx + 20.0) / 25.4 * DPI) as usize;
        let black = row[x_lo..x_hi].iter().filter(|v| **v == 0).count();
        assert!(
            (black as f64 - 16.0 / 25.4 * DPI).abs() <= 2.0,
            "{black} px"
        );
        // Scale bar: 50 mm = 590.6 px.
        let y = ((245.0 + 1.0) / 25.4 * DPI) as usize;
        let row = &img.data[y * img.width..(y + 1) * img.width];
        let black = row.iter().filter(|v| **v == 0).count();
        assert!(
            (black as f64 - 50.0 / 25.4 * DPI).abs() <= 1.5,
            "{black} px"
        );
    }

    #[test]
    fn svg_states_sizes_in_millimetres_and_rejects_bad_sizes() {
        let s = svg(&fake(), 16.0, "DICT_6X6_250").expect("svg");
        assert!(s.contains(r#"width="210mm""#) && s.contains("DICT_6X6_250, 1.6 cm"));
        assert!(s.contains("id 3 (bottom-left corner)"));
        assert!(svg(&fake(), 100.0, "x").is_err());
        assert!(svg(&fake()[..3], 16.0, "x").is_err());
    }
}
