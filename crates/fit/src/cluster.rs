//! Initial clusters (paper section 3.2.1): k-means with k-means++ seeding on the
//! per-pixel average colour in CIE L*a*b*, with k chosen by the elbow of the summed
//! squared error over a range of k.

use std::collections::VecDeque;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use svbrdf_core::color::linear_rgb_to_lab;

/// A point in L*a*b*.
pub type Lab = [f64; 3];

fn dist2(a: &Lab, b: &Lab) -> f64 {
    (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)
}

/// Index of the nearest centre and the squared distance to it.
pub fn nearest(p: &Lab, centres: &[Lab]) -> (usize, f64) {
    let mut best = (0, f64::INFINITY);
    for (i, c) in centres.iter().enumerate() {
        let d = dist2(p, c);
        if d < best.1 {
            best = (i, d);
        }
    }
    best
}

/// Squared distances between every pair of centres (`k x k`, row-major) and, per
/// centre, the smallest of them to another centre.
struct CentreGaps {
    k: usize,
    between: Vec<f64>,
    closest: Vec<f64>,
}

impl CentreGaps {
    fn new(centres: &[Lab]) -> Self {
        let k = centres.len();
        let mut between = vec![0.0; k * k];
        let mut closest = vec![f64::INFINITY; k];
        for a in 0..k {
            for b in 0..k {
                if a != b {
                    let d = dist2(&centres[a], &centres[b]);
                    between[a * k + b] = d;
                    closest[a] = closest[a].min(d);
                }
            }
        }
        Self {
            k,
            between,
            closest,
        }
    }

    /// Whether every point at squared distance `d` from a centre is strictly nearer to
    /// it than to a centre at squared distance `gap` from it: `sqrt(gap) > 2 sqrt(d)`
    /// (triangle inequality), with a relative margin far above rounding and an absolute
    /// floor, so that no tie is ever decided by the bound.
    fn separates(gap: f64, d: f64) -> bool {
        gap > 4.0 * d * (1.0 + 1e-9) + 1e-12
    }
}

/// [`nearest`] with the same result to the last bit (the same index, ties to the lowest
/// index, and the same distance), sooner: the centre `hint` (any index below `k`) is
/// measured first, and centres the triangle inequality puts strictly farther than it
/// are not measured. Lloyd's iterations pass each point's last centre.
fn nearest_from(p: &Lab, centres: &[Lab], gaps: &CentreGaps, hint: usize) -> (usize, f64) {
    let dh = dist2(p, &centres[hint]);
    // Every other centre is strictly farther: only `hint` can be the nearest.
    if CentreGaps::separates(gaps.closest[hint], dh) {
        return (hint, dh);
    }
    let row = &gaps.between[hint * gaps.k..(hint + 1) * gaps.k];
    let mut best = (0, f64::INFINITY);
    for (i, c) in centres.iter().enumerate() {
        let d = if i == hint {
            dh
        } else if CentreGaps::separates(row[i], dh) {
            // Strictly farther than `hint`, so never the (first) nearest.
            continue;
        } else {
            dist2(p, c)
        };
        if d < best.1 {
            best = (i, d);
        }
    }
    best
}

/// Lloyd's k-means with k-means++ seeding; returns the centres and the summed squared
/// error. Deterministic for a seed.
pub fn kmeans(points: &[Lab], k: usize, seed: u64, iterations: usize) -> (Vec<Lab>, f64) {
    lloyd(points, k, seed, iterations, true)
}

/// [`kmeans`], each point's nearest centre found by [`nearest_from`] when `prune`, else
/// by measuring every centre ([`nearest`]); the two give the same bits.
fn lloyd(points: &[Lab], k: usize, seed: u64, iterations: usize, prune: bool) -> (Vec<Lab>, f64) {
    if points.is_empty() || k == 0 {
        return (Vec::new(), 0.0);
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut centres = vec![points[rng.random_range(0..points.len())]];
    let mut d2: Vec<f64> = points.iter().map(|p| dist2(p, &centres[0])).collect();
    // Each point's centre (a seed, then its centre in the last iteration): where its
    // nearest-centre search starts. Any start gives the same result; a good one is faster.
    let mut labels = vec![0usize; points.len()];
    while centres.len() < k {
        let total: f64 = d2.iter().sum();
        let next = if total > 0.0 {
            let mut t = rng.random::<f64>() * total;
            let mut pick = points.len() - 1;
            for (i, d) in d2.iter().enumerate() {
                t -= d;
                if t <= 0.0 {
                    pick = i;
                    break;
                }
            }
            pick
        } else {
            rng.random_range(0..points.len())
        };
        let c = points[next];
        centres.push(c);
        // Each point's nearest seed so far: where its first search below starts.
        for ((d, l), p) in d2.iter_mut().zip(labels.iter_mut()).zip(points) {
            let e = dist2(p, &c);
            if e < *d {
                *l = centres.len() - 1;
            }
            *d = d.min(e);
        }
    }
    let mut sse = f64::INFINITY;
    for _ in 0..iterations {
        let mut sums = vec![[0.0; 4]; k];
        let mut new_sse = 0.0;
        let gaps = CentreGaps::new(&centres);
        for (p, label) in points.iter().zip(labels.iter_mut()) {
            let (i, d) = if prune {
                nearest_from(p, &centres, &gaps, *label)
            } else {
                nearest(p, &centres)
            };
            *label = i;
            new_sse += d;
            for j in 0..3 {
                sums[i][j] += p[j];
            }
            sums[i][3] += 1.0;
        }
        for (c, s) in centres.iter_mut().zip(&sums) {
            if s[3] > 0.0 {
                *c = [s[0] / s[3], s[1] / s[3], s[2] / s[3]];
            }
        }
        let done = new_sse >= sse * (1.0 - 1e-6);
        sse = new_sse;
        if done {
            break;
        }
    }
    let gaps = CentreGaps::new(&centres);
    let sse = points
        .iter()
        .zip(&labels)
        .map(|(p, &l)| {
            if prune {
                nearest_from(p, &centres, &gaps, l).1
            } else {
                nearest(p, &centres).1
            }
        })
        .sum();
    (centres, sse)
}

/// The elbow of a decreasing error curve: the k whose error lies farthest below the
/// straight line from the first to the last point (the paper's "linear bisection
/// point"). `curve[i]` is the error for `k_min + i`.
pub fn elbow(k_min: usize, curve: &[f64]) -> usize {
    let n = curve.len();
    if n < 3 {
        return k_min;
    }
    let (a, b) = (curve[0], curve[n - 1]);
    let mut best = (0, f64::NEG_INFINITY);
    for (i, &e) in curve.iter().enumerate() {
        let line = a + (b - a) * i as f64 / (n - 1) as f64;
        if line - e > best.1 {
            best = (i, line - e);
        }
    }
    k_min + best.0
}

/// Result of the initial clustering.
#[derive(Debug, Clone)]
pub struct InitialClusters {
    /// The chosen k.
    pub k: usize,
    /// Summed squared error per k, from `k_min`.
    pub sse: Vec<f64>,
    /// Centres in L*a*b*.
    pub centres: Vec<Lab>,
    /// Cluster per input colour.
    pub labels: Vec<u32>,
}

/// Cluster linear colours: L*a*b* of the colours normalised by the brightest one (the
/// paper clusters "normalised albedo colour"), k-means on an even sample of at most
/// `sample` colours for every k in `k_min..=k_max`, elbow, then every colour to its
/// nearest centre.
pub fn initial_clusters(
    colors: &[[f64; 3]],
    k_min: usize,
    k_max: usize,
    sample: usize,
    seed: u64,
) -> InitialClusters {
    let peak = colors
        .iter()
        .flat_map(|c| c.iter().copied())
        .fold(1e-9, f64::max);
    let lab: Vec<Lab> = colors
        .par_iter()
        .map(|c| linear_rgb_to_lab(c.map(|v| v / peak)))
        .collect();
    // A random sample, not every n-th pixel: a regular stride aliases with periodic
    // textures (tiles, weaves) and can miss a whole colour.
    let sub: Vec<Lab> = if lab.len() <= sample {
        lab.clone()
    } else {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x00c0_ffee);
        let mut idx = rand::seq::index::sample(&mut rng, lab.len(), sample).into_vec();
        idx.sort_unstable();
        idx.into_iter().map(|i| lab[i]).collect()
    };
    let k_max = k_max.min(sub.len()).max(1);
    let k_min = k_min.min(k_max);
    let runs: Vec<(Vec<Lab>, f64)> = (k_min..=k_max)
        .into_par_iter()
        .map(|k| {
            // Lloyd's iterations find local minima; the best of a few seedings makes the
            // error curve (and so the elbow) stable.
            (0..4u64)
                .map(|r| kmeans(&sub, k, seed.wrapping_add(1000 * r + k as u64), 50))
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .unwrap_or_default()
        })
        .collect();
    let sse: Vec<f64> = runs.iter().map(|r| r.1).collect();
    let k = elbow(k_min, &sse);
    let centres = runs[k - k_min].0.clone();
    let labels = lab
        .par_iter()
        .map(|p| nearest(p, &centres).0 as u32)
        .collect();
    InitialClusters {
        k,
        sse,
        centres,
        labels,
    }
}

/// Give every unobserved pixel the cluster of its nearest observed pixel (4-connected
/// breadth-first fill), so that no output pixel is left without a BRDF.
pub(crate) fn fill_unobserved(
    grid: &svbrdf_core::plane::PlaneGrid,
    cluster: &mut [u32],
    known: &[bool],
) {
    let (w, h) = (grid.width, grid.height);
    let mut seen = known.to_vec();
    let mut queue: VecDeque<usize> = (0..w * h).filter(|&p| known[p]).collect();
    while let Some(p) = queue.pop_front() {
        let (x, y) = (p % w, p / w);
        let mut push = |q: usize| {
            if !seen[q] {
                seen[q] = true;
                cluster[q] = cluster[p];
                queue.push_back(q);
            }
        };
        if x > 0 {
            push(p - 1);
        }
        if x + 1 < w {
            push(p + 1);
        }
        if y > 0 {
            push(p - w);
        }
        if y + 1 < h {
            push(p + w);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn elbow_finds_the_knee() {
        // Error drops steeply until k = 4, then flattens.
        let curve = [100.0, 60.0, 20.0, 15.0, 13.0, 12.0, 11.0, 10.5];
        assert_eq!(elbow(2, &curve), 4);
        assert_eq!(elbow(2, &[5.0, 4.0]), 2);
    }

    fn bits(r: &(Vec<Lab>, f64)) -> (Vec<[u64; 3]>, u64) {
        (
            r.0.iter().map(|c| c.map(f64::to_bits)).collect(),
            r.1.to_bits(),
        )
    }

    #[test]
    fn pruned_kmeans_gives_the_same_bits_as_measuring_every_centre() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        // Clustered colours, overlapping clusters, and points on an integer grid
        // (exact ties between centres, repeated points, points on centres).
        let clustered: Vec<Lab> = (0..3000)
            .map(|i| {
                let c = [(i % 7) as f64 * 12.0, (i % 3) as f64 * 9.0 - 9.0, 4.0];
                c.map(|v| v + 3.0 * (rng.random::<f64>() - 0.5))
            })
            .collect();
        let spread: Vec<Lab> = (0..2000)
            .map(|_| [0; 3].map(|_: i32| 100.0 * rng.random::<f64>()))
            .collect();
        let grid: Vec<Lab> = (0..1500)
            .map(|i| [(i % 5) as f64, ((i / 5) % 4) as f64, 0.0])
            .collect();
        for points in [&clustered, &spread, &grid] {
            for k in [1, 2, 3, 5, 8, 13, 20] {
                for seed in 0..3u64 {
                    let a = kmeans(points, k, seed, 50);
                    let b = lloyd(points, k, seed, 50, false);
                    assert_eq!(bits(&a), bits(&b), "k {k} seed {seed}");
                }
            }
        }
    }

    #[test]
    fn the_bound_never_decides_a_tie() {
        // Two centres at squared distance 4 and a point at squared distance 1 from the
        // first: the point is exactly between them only at the bound's limit, so the
        // bound must not skip the second centre.
        assert!(!CentreGaps::separates(4.0, 1.0));
        assert!(CentreGaps::separates(4.0 + 1e-6, 1.0));
        assert!(!CentreGaps::separates(0.0, 0.0));
        assert!(!CentreGaps::separates(f64::NAN, 1.0));
        assert!(!CentreGaps::separates(4.0, f64::NAN));
    }

    #[test]
    fn four_colours_give_four_clusters_deterministically() {
        let base = [
            [0.6, 0.1, 0.1],
            [0.1, 0.5, 0.1],
            [0.1, 0.1, 0.6],
            [0.5, 0.5, 0.45],
        ];
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let colors: Vec<[f64; 3]> = (0..4000)
            .map(|i| base[i % 4].map(|v: f64| v * (1.0 + 0.03 * (rng.random::<f64>() - 0.5))))
            .collect();
        let a = initial_clusters(&colors, 2, 10, 2000, 7);
        assert_eq!(a.k, 4, "sse {:?}", a.sse);
        // Same colour, same label; different colour, different label.
        for i in 0..8 {
            assert_eq!(
                a.labels[i],
                a.labels[i + 4],
                "{:?} {:?}",
                a.centres,
                &a.labels[..12]
            );
        }
        let mut l: Vec<u32> = a.labels[..4].to_vec();
        l.sort_unstable();
        l.dedup();
        assert_eq!(l.len(), 4);
        let b = initial_clusters(&colors, 2, 10, 2000, 7);
        assert_eq!(a.labels, b.labels);
    }
}
