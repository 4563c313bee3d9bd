//! How sure a goal count is: the Wilson score interval of a share (DESIGN.md, "Metrics").

/// The 95 % Wilson score interval of `successes` in `trials` (Wilson 1927), `(0, 1)` for no
/// trials. Unlike the normal approximation it stays inside [0, 1] and is honest near 0 and
/// 1 of 20, where this project's goal counts live.
pub fn wilson_interval(successes: usize, trials: usize) -> (f64, f64) {
    if trials == 0 {
        return (0.0, 1.0);
    }
    const Z: f64 = 1.959_963_984_540_054;
    let n = trials as f64;
    let p = successes as f64 / n;
    let denominator = 1.0 + Z * Z / n;
    let centre = (p + Z * Z / (2.0 * n)) / denominator;
    let half = Z * (p * (1.0 - p) / n + Z * Z / (4.0 * n * n)).sqrt() / denominator;
    ((centre - half).max(0.0), (centre + half).min(1.0))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_interval_matches_published_values() {
        // 13 of 20: 0.433-0.819 (as statsmodels' proportion_confint(method="wilson") gives).
        let (low, high) = wilson_interval(13, 20);
        assert!(
            (low - 0.4329).abs() < 1e-3 && (high - 0.8188).abs() < 1e-3,
            "{low} {high}"
        );
        // 85 of 100: 0.767-0.907, the bar for the shipped model.
        let (low, high) = wilson_interval(85, 100);
        assert!(
            (low - 0.7672).abs() < 1e-3 && (high - 0.9069).abs() < 1e-3,
            "{low} {high}"
        );
        assert_eq!(wilson_interval(0, 0), (0.0, 1.0));
        let (low, high) = wilson_interval(20, 20);
        assert!(low > 0.83 && high == 1.0);
        let (low, _) = wilson_interval(0, 20);
        assert_eq!(low, 0.0);
    }
}
