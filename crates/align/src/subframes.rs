//! Sub-frames (paper 3.1.4): the grid of rectangles each frame is split into, each
//! with its own homography in the global solve.

use svbrdf_core::geometry::{Mat3, Vec2};

use crate::config::AlignConfig;

/// How far in (shares of the cell's size) the edge of a sub-frame on the frame's edge
/// may move ([`Grid::cut_rect`]): up to the middle of its cell.
pub(crate) const EDGE_INSETS: [f64; 11] =
    [0.0, 0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.45, 0.5];

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

    /// Points along the frame's edges a sub-frame lies on, where its map's uncertainty
    /// decides how far towards the edge it is used ([`cut_rect`](Self::cut_rect)): for
    /// each such edge (left, top, right, bottom), for each of [`EDGE_INSETS`], three
    /// points across the sub-frame.
    pub(crate) fn edge_probes(&self, k: usize) -> Vec<Vec2> {
        let r = self.rect(k);
        let mut out = Vec::new();
        for edge in self.outer_edges(k) {
            for t in EDGE_INSETS {
                let at = self.inset(k, edge, t);
                for s in [0.1, 0.5, 0.9] {
                    out.push(if edge % 2 == 0 {
                        Vec2::new(at, r[1] + s * (r[3] - r[1]))
                    } else {
                        Vec2::new(r[0] + s * (r[2] - r[0]), at)
                    });
                }
            }
        }
        out
    }

    /// The rectangle where sub-frame `k`'s map is used: [`rect`](Self::rect), with each
    /// edge it shares with the frame moved in to the first of [`EDGE_INSETS`] where the
    /// noise gain at all three [`edge_probes`](Self::edge_probes) is at most `limit`
    /// (`gains` in the order of the probes), at most to the middle of its cell.
    pub(crate) fn cut_rect(&self, k: usize, gains: &[f64], limit: f64) -> [f64; 4] {
        let mut r = self.rect(k);
        let per_edge = 3 * EDGE_INSETS.len();
        for (n, edge) in self.outer_edges(k).into_iter().enumerate() {
            let first = (0..EDGE_INSETS.len()).find(|&i| {
                let at = n * per_edge + 3 * i;
                gains
                    .get(at..at + 3)
                    .is_some_and(|g| g.iter().all(|g| *g <= limit))
            });
            let t = EDGE_INSETS[first.unwrap_or(EDGE_INSETS.len() - 1)];
            r[edge] = self.inset(k, edge, t);
        }
        r
    }

    /// The frame edges sub-frame `k` lies on: 0 left, 1 top, 2 right, 3 bottom (the
    /// index of that side in a rectangle).
    fn outer_edges(&self, k: usize) -> Vec<usize> {
        let (c, row) = (k % self.cols, k / self.cols);
        [c == 0, row == 0, c + 1 == self.cols, row + 1 == self.rows]
            .into_iter()
            .enumerate()
            .filter_map(|(edge, on)| on.then_some(edge))
            .collect()
    }

    /// Where sub-frame `k`'s `edge` lies when moved in by `t` of its cell's size.
    fn inset(&self, k: usize, edge: usize, t: f64) -> f64 {
        let r = self.rect(k);
        let (cw, ch) = (self.w / self.cols as f64, self.h / self.rows as f64);
        match edge {
            0 => r[0] + t * cw,
            1 => r[1] + t * ch,
            2 => r[2] - t * cw,
            _ => r[3] - t * ch,
        }
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

#[cfg(test)]
mod tests {
    use super::*;

    fn grid() -> Grid {
        // 540 x 960: the default 3 x 5 grid, cells 180 x 192.
        Grid::new(540, 960, &AlignConfig::default())
    }

    #[test]
    fn edge_probes_lie_on_the_frame_edges_a_sub_frame_shares() {
        let g = grid();
        let per_edge = 3 * EDGE_INSETS.len();
        // Corner (left and top), edge (top), inside (none).
        assert_eq!(g.edge_probes(0).len(), 2 * per_edge);
        assert_eq!(g.edge_probes(1).len(), per_edge);
        assert_eq!(g.edge_probes(4).len(), 0);
        // The bottom-right corner: right edge first, at the rectangle's edge, then
        // moving in; then the bottom edge.
        let k = g.len() - 1;
        let (r, p) = (g.rect(k), g.edge_probes(k));
        assert_eq!(p[0].x, r[2]);
        assert_eq!(p[3].x, r[2] - 0.05 * 180.0);
        assert_eq!(p[per_edge].y, r[3]);
        assert!(p
            .iter()
            .all(|q| q.x >= r[0] && q.x <= r[2] && q.y >= r[1] && q.y <= r[3]));
    }

    #[test]
    fn cut_rect_moves_an_edge_in_to_where_the_gain_falls() {
        let g = grid();
        let per_edge = 3 * EDGE_INSETS.len();
        // Top-left corner: everything well fixed, nothing moves.
        assert_eq!(g.cut_rect(0, &vec![0.5; 2 * per_edge], 1.5), g.rect(0));
        // The left edge's gain falls below the limit 0.15 of a cell in; one of the
        // three points at 0.1 is still above it.
        let mut gains = vec![0.5; 2 * per_edge];
        for v in &mut gains[..6] {
            *v = 3.0;
        }
        gains[7] = 1.6;
        let r = g.cut_rect(0, &gains, 1.5);
        assert_eq!(r[0], g.rect(0)[0] + 0.15 * 180.0);
        assert_eq!(&r[1..], &g.rect(0)[1..]);
        // Nowhere below the limit along the top edge: in to the middle, no further.
        let mut gains = vec![0.5; 2 * per_edge];
        for v in &mut gains[per_edge..] {
            *v = 9.0;
        }
        let r = g.cut_rect(0, &gains, 1.5);
        assert_eq!(r[1], g.rect(0)[1] + 0.5 * 192.0);
        assert_eq!(r[0], g.rect(0)[0]);
        // An inside sub-frame has no frame edge to cut.
        assert_eq!(g.cut_rect(7, &[], 1.5), g.rect(7));
        // Missing gains (a frame whose normal matrix was singular) cut to the middle.
        let r = g.cut_rect(1, &[], 1.5);
        assert_eq!(r[1], g.rect(1)[1] + 0.5 * 192.0);
    }
}
