//! The detector effects beyond the EMVA 1288 reference chain that the
//! simulated facility's camera has (and `render` may switch on): the
//! non-linearity e (1 − β e / full_well) of the collected charge, a per-row
//! offset (the same along a row of one frame), and shot noise off (the mean
//! charge instead of a Poisson draw, for tests of the optics that need a
//! deterministic frame). All are off by default.

/// The charge after the non-linearity β: e (1 − β e / full_well) up to the
/// full well, and beyond it the straight line of the curve's slope there,
/// 1 − 2β, so the response is continuous and monotone for β ≤ 1/2 and the
/// clip at [`response`]`(full_well)` after the read noise caps it. With
/// β = 0 it is e itself, so the reference chain is unchanged.
#[inline]
pub fn response(electrons: f64, beta: f64, full_well: f64) -> f64 {
    if beta == 0.0 {
        return electrons;
    }
    if electrons <= full_well {
        electrons * (1.0 - beta * electrons / full_well)
    } else {
        full_well * (1.0 - beta) + (electrons - full_well) * (1.0 - 2.0 * beta)
    }
}

/// One frame's row offsets [e⁻]: σ_row · N(0, 1) per row, drawn from the
/// frame's stream at the indices after its pixels' (`pixels + j` for row
/// j), so they never share a draw with a pixel of any frame. Zeros when
/// σ_row is 0.
pub fn row_offsets(
    stream: &super::rng::Stream,
    pixels: usize,
    height: usize,
    sigma: f64,
) -> Vec<f64> {
    if sigma <= 0.0 {
        return vec![0.0; height];
    }
    (0..height)
        .map(|j| sigma * stream.at((pixels + j) as u64).normal_fast())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn response_is_the_quadratic_then_its_tangent() {
        let (beta, fw) = (0.04, 1000.0);
        // Half well: 500 (1 − 0.04 · 0.5) = 490; full well: 960.
        assert!((response(500.0, beta, fw) - 490.0).abs() < 1e-12);
        assert!((response(1000.0, beta, fw) - 960.0).abs() < 1e-12);
        // 100 e⁻ past it, slope 1 − 0.08.
        assert!((response(1100.0, beta, fw) - (960.0 + 92.0)).abs() < 1e-12);
        assert_eq!(response(1234.5, 0.0, fw), 1234.5);
        // Monotone at the steepest allowed β.
        let ys: Vec<f64> = (0..300)
            .map(|k| response(k as f64 * 5.0, 0.5, fw))
            .collect();
        assert!(ys.windows(2).all(|p| p[1] >= p[0]));
    }

    #[test]
    fn row_offsets_have_their_sigma_and_skip_the_pixels_draws() {
        let stream = super::super::rng::Stream::new(3, 1 << 32);
        let rows = row_offsets(&stream, 100, 50_000, 2.0);
        let m = rows.iter().sum::<f64>() / rows.len() as f64;
        let v = rows.iter().map(|r| (r - m).powi(2)).sum::<f64>() / rows.len() as f64;
        // Standard errors: 2/√n = 0.009 for the mean, 4·√(2/n) = 0.025 for
        // the variance; 4 of each.
        assert!(m.abs() < 0.036 && (v / 4.0 - 1.0).abs() < 0.026, "{m} {v}");
        assert_eq!(rows[0], 2.0 * stream.at(100).normal_fast());
        assert_eq!(row_offsets(&stream, 100, 3, 0.0), vec![0.0; 3]);
    }
}
