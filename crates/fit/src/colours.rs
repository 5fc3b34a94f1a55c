//! Per-pixel colours: the mean of a pixel's observations (the average map, and what
//! the initial clusters group by default) and the colour an albedo would show
//! (`cluster_colour: albedo`).

use rayon::prelude::*;

use crate::observations::Observations;

impl Observations {
    /// Per-pixel colour as an albedo would show it: the median, per channel, of the
    /// unclipped observations divided by the flash's irradiance factor
    /// `cos(theta_i) / r^2` at the flat normal (1/cm^2). Unlike the mean, it is not
    /// brightened where the flash's highlight passed over a glossy pixel in a few
    /// frames, nor darkened where the frames saw a pixel from afar (the initial
    /// clusters' colours with `cluster_colour: albedo`).
    /// Pixels without an unclipped observation take their mean colour over the mean
    /// irradiance factor; unobserved ones are zero.
    pub fn albedo_colors(&self) -> Vec<[f64; 3]> {
        (0..self.pixels())
            .into_par_iter()
            .map_init(
                || [Vec::new(), Vec::new(), Vec::new()],
                |vals: &mut [Vec<f64>; 3], p| {
                    for v in vals.iter_mut() {
                        v.clear();
                    }
                    let (mut mean, mut irr, mut n) = ([0.0; 3], 0.0, 0usize);
                    for o in self.range(p) {
                        let lv = self.light_view(p, o);
                        let e = lv.light.z / lv.light_dist2.max(1e-12);
                        if e.is_nan() || e <= 0.0 {
                            continue;
                        }
                        let c = self.color(o);
                        for k in 0..3 {
                            mean[k] += c[k];
                        }
                        irr += e;
                        n += 1;
                        if self.clipped(o).iter().any(|&b| b) {
                            continue;
                        }
                        for k in 0..3 {
                            vals[k].push(c[k] / e);
                        }
                    }
                    if vals[0].is_empty() {
                        return if n > 0 && irr > 0.0 {
                            mean.map(|v| v / irr)
                        } else {
                            [0.0; 3]
                        };
                    }
                    let mut out = [0.0; 3];
                    for k in 0..3 {
                        let v = &mut vals[k];
                        let mid = v.len() / 2;
                        v.select_nth_unstable_by(mid, f64::total_cmp);
                        out[k] = v[mid];
                    }
                    out
                },
            )
            .collect()
    }

    /// Per-pixel mean linear colour (zero where unobserved).
    pub fn mean_colors(&self) -> Vec<[f64; 3]> {
        (0..self.pixels())
            .into_par_iter()
            .map(|p| {
                let r = self.range(p);
                let n = r.len().max(1) as f64;
                let mut s = [0.0; 3];
                for o in r {
                    let c = self.color(o);
                    for k in 0..3 {
                        s[k] += c[k];
                    }
                }
                s.map(|v| v / n)
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use crate::observations::{flash_frames, rendered};
    use svbrdf_core::geometry::Vec3;
    use svbrdf_core::plane::PlaneGrid;

    #[test]
    fn albedo_colours_are_neither_brightened_by_highlights_nor_darkened_by_distance() {
        // One glossy material over 8 x 8 cm, filmed from 9 cm above a 5 x 5 grid over
        // its left half only: the mean colour falls off towards the right and peaks
        // where highlights passed (over 10x from darkest to brightest pixel); the albedo
        // colour varies far less (2.5x: where the highlight is in most of a pixel's
        // frames it still sets the median) and is rho_d I / pi in the middle.
        let grid = PlaneGrid::new(svbrdf_core::plane::Region::centred(8.0, 8.0), 5.0).unwrap();
        let frames = flash_frames(25, |i| {
            Vec3::new(-3.0 + 0.5 * f64::from(i % 5), f64::from(i / 5) - 2.0, 9.0)
        });
        let truth = svbrdf_core::brdf::BrdfParams {
            rho_d: [0.3, 0.2, 0.1],
            rho_s: [0.3; 3],
            alpha_x: 0.08,
            alpha_y: 0.08,
            ..Default::default()
        };
        let intensity = 20.0;
        let obs = rendered(grid, frames, |_| truth, intensity, true);
        let spread = |c: &[[f64; 3]]| {
            let v: Vec<f64> = c.iter().map(|c| c[0]).filter(|v| *v > 0.0).collect();
            let (lo, hi) = v
                .iter()
                .fold((f64::MAX, 0.0f64), |(a, b), x| (a.min(*x), b.max(*x)));
            hi / lo
        };
        let (mean, albedo) = (obs.mean_colors(), obs.albedo_colors());
        assert!(spread(&mean) > 5.0, "{}", spread(&mean));
        assert!(
            spread(&albedo) < spread(&mean) / 3.0,
            "{} against {}",
            spread(&albedo),
            spread(&mean)
        );
        let want = truth.rho_d[0] * intensity / std::f64::consts::PI;
        let mid = albedo[grid.len() / 2 + grid.width / 2][0];
        assert!((mid / want - 1.0).abs() < 0.35, "{mid} against {want}");
    }
}
