//! Sub-frames (paper 3.1.4): the grid of rectangles each frame is split into, each
//! with its own homography in the global solve.

use svbrdf_core::geometry::{Mat3, Vec2};

use crate::config::AlignConfig;

/// Sub-frame layout of one frame: rectangles with overlap, and the core cells.
pub(crate) struct Grid {
    pub(crate) cols: usize,
    pub(crate) rows: usize,
    pub(crate) w: f64,
    pub(crate) h: f64,
    pub(crate) ox: f64,
    pub(crate) oy: f64,
}

impl Grid {
    pub(crate) fn new(width: u32, height: u32, cfg: &AlignConfig) -> Self {
        let (w, h) = (f64::from(width), f64::from(height));
        let (cols, rows) = match cfg.subframes {
            Some((c, r)) => (c as usize, r as usize),
            None => {
                // The paper's 5 x 11 at 2160 x 3840 (portrait), at least 3 x 5.
                let (short, long) = (w.min(h), w.max(h));
                let a = ((5.0 * short / 2160.0).round() as usize).max(3);
                let b = ((11.0 * long / 3840.0).round() as usize).max(5);
                if h >= w {
                    (a, b)
                } else {
                    (b, a)
                }
            }
        };
        // Paper: 25 and 22 px overlap at 2160 x 3840.
        let s = w.max(h) / 3840.0;
        Self {
            cols,
            rows,
            w,
            h,
            ox: (25.0 * s).max(4.0),
            oy: (22.0 * s).max(4.0),
        }
    }

    pub(crate) fn len(&self) -> usize {
        self.cols * self.rows
    }

    pub(crate) fn cell(&self, p: Vec2) -> usize {
        let c = (((p.x + 0.5) / self.w * self.cols as f64).floor() as isize)
            .clamp(0, self.cols as isize - 1) as usize;
        let r = (((p.y + 0.5) / self.h * self.rows as f64).floor() as isize)
            .clamp(0, self.rows as isize - 1) as usize;
        r * self.cols + c
    }

    /// Rectangle `[x0, y0, x1, y1]` of a sub-frame including its overlap.
    pub(crate) fn rect(&self, k: usize) -> [f64; 4] {
        let (c, r) = ((k % self.cols) as f64, (k / self.cols) as f64);
        let (cw, ch) = (self.w / self.cols as f64, self.h / self.rows as f64);
        [
            (c * cw - 0.5 - self.ox).max(-0.5),
            (r * ch - 0.5 - self.oy).max(-0.5),
            ((c + 1.0) * cw - 0.5 + self.ox).min(self.w - 0.5),
            ((r + 1.0) * ch - 0.5 + self.oy).min(self.h - 0.5),
        ]
    }

    /// Sample points on the shared borders of neighbouring cells: (cell a, cell b, point).
    pub(crate) fn seams(&self) -> Vec<(usize, usize, Vec2)> {
        let (cw, ch) = (self.w / self.cols as f64, self.h / self.rows as f64);
        let mut out = Vec::new();
        for r in 0..self.rows {
            for c in 0..self.cols {
                let k = r * self.cols + c;
                for t in [0.1, 0.5, 0.9] {
                    if c + 1 < self.cols {
                        let x = (c + 1) as f64 * cw - 0.5;
                        for dx in [-self.ox, 0.0, self.ox] {
                            out.push((k, k + 1, Vec2::new(x + dx, (r as f64 + t) * ch - 0.5)));
                        }
                    }
                    if r + 1 < self.rows {
                        let y = (r + 1) as f64 * ch - 0.5;
                        for dy in [-self.oy, 0.0, self.oy] {
                            out.push((
                                k,
                                k + self.cols,
                                Vec2::new((c as f64 + t) * cw - 0.5, y + dy),
                            ));
                        }
                    }
                }
            }
        }
        out
    }
}

/// Normalisation of frame pixels for conditioning: centred, long side = 2.
pub(crate) fn normaliser(w: u32, h: u32) -> Mat3 {
    let s = 2.0 / f64::from(w.max(h));
    Mat3::new(
        s,
        0.0,
        -s * 0.5 * (f64::from(w) - 1.0),
        0.0,
        s,
        -s * 0.5 * (f64::from(h) - 1.0),
        0.0,
        0.0,
        1.0,
    )
}
