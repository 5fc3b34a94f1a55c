//! The blur metric of eq. (1): `f = mean(log10(0.001 + |F(i)|))` over the 2-D Fourier
//! transform of the grey image (values in [0, 1]). Sharp frames keep more high
//! frequencies and score higher.

use rustfft::num_complex::Complex;
use rustfft::FftPlanner;

/// Eq. (1) for a grey image stored row-major with values in [0, 1].
pub fn blur_metric(grey: &[f32], width: usize, height: usize) -> f64 {
    if width == 0 || height == 0 || grey.len() != width * height {
        return f64::NAN;
    }
    let mut planner = FftPlanner::<f32>::new();
    let row_fft = planner.plan_fft_forward(width);
    let col_fft = planner.plan_fft_forward(height);
    let mut data: Vec<Complex<f32>> = grey.iter().map(|v| Complex::new(*v, 0.0)).collect();
    for row in data.chunks_exact_mut(width) {
        row_fft.process(row);
    }
    let mut col = vec![Complex::new(0.0, 0.0); height];
    let mut sum = 0.0f64;
    for c in 0..width {
        for r in 0..height {
            col[r] = data[r * width + c];
        }
        col_fft.process(&mut col);
        sum += col
            .iter()
            .map(|z| f64::from(0.001 + z.norm()).log10())
            .sum::<f64>();
    }
    sum / (width * height) as f64
}

/// The metric below which a frame is blurry: `sigmas` standard deviations below the
/// mean over all frames (`None` with fewer than 3 frames: no statistics).
pub fn blur_threshold(metrics: &[f64], sigmas: f64) -> Option<f64> {
    if metrics.len() < 3 {
        return None;
    }
    let n = metrics.len() as f64;
    let mean = metrics.iter().sum::<f64>() / n;
    let sd = (metrics.iter().map(|m| (m - mean).powi(2)).sum::<f64>() / n).sqrt();
    Some(mean - sigmas * sd)
}

/// Indices of frames to drop: metric more than `sigmas` standard deviations below the
/// mean over all frames.
pub fn blurry_frames(metrics: &[f64], sigmas: f64) -> Vec<usize> {
    let Some(t) = blur_threshold(metrics, sigmas) else {
        return Vec::new();
    };
    metrics
        .iter()
        .enumerate()
        .filter(|(_, m)| **m < t)
        .map(|(i, _)| i)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pattern(w: usize, h: usize, blur: usize) -> Vec<f32> {
        let sharp: Vec<f32> = (0..w * h)
            .map(|i| {
                if ((i % w) / 3 + (i / w) / 3).is_multiple_of(2) {
                    1.0
                } else {
                    0.0
                }
            })
            .collect();
        if blur == 0 {
            return sharp;
        }
        (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                let mut s = 0.0;
                let mut n = 0.0;
                for dx in 0..=2 * blur {
                    let xx = (x + dx).saturating_sub(blur).min(w - 1);
                    s += sharp[y * w + xx];
                    n += 1.0;
                }
                s / n
            })
            .collect()
    }

    #[test]
    fn blurred_image_scores_lower_and_is_dropped() {
        let (w, h) = (64, 48);
        let sharp = blur_metric(&pattern(w, h, 0), w, h);
        let soft = blur_metric(&pattern(w, h, 3), w, h);
        assert!(soft < sharp, "{soft} !< {sharp}");
        let mut metrics = vec![sharp; 10];
        metrics.push(soft);
        assert_eq!(blurry_frames(&metrics, 1.5), vec![10]);
    }
}
