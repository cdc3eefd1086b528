//! Pareto fronts of (time, error) points, GPU-free.
//!
//! Both coordinates are "lower is better": milliseconds per frame and the mean
//! squared error against the reference (PSNR is `10 log10(255^2 / MSE)`, so a
//! front in MSE is the front in PSNR). A point is **on the front** when no other
//! point is at least as fast and at least as accurate and better in one. A point
//! is **within `eps` of the front** (multiplicative epsilon-dominance) when no
//! point is faster by more than the factor `1 - eps` *and* more accurate by more
//! than that factor: improving the point by `eps` on both axes would put it on
//! or beyond the front. With `eps = 0.05`, 5% in MSE is 0.22 dB of PSNR.

/// Indices of the points on the front, by increasing time. Points with a
/// non-finite coordinate are never on it (and dominate nothing).
pub(crate) fn front(points: &[(f64, f64)]) -> Vec<usize> {
    let finite = |&(t, e): &(f64, f64)| t.is_finite() && e.is_finite();
    let mut on: Vec<usize> = (0..points.len())
        .filter(|&i| finite(&points[i]))
        .filter(|&i| {
            let (ti, ei) = points[i];
            !points.iter().enumerate().any(|(j, p)| {
                j != i && finite(p) && p.0 <= ti && p.1 <= ei && (p.0 < ti || p.1 < ei)
            })
        })
        .collect();
    on.sort_by(|&a, &b| points[a].0.total_cmp(&points[b].0));
    on
}

/// Whether point `i` is within `eps` (a fraction) of the front: no point has
/// time `<= (1 - eps) t_i` and error `<= (1 - eps) e_i`.
pub(crate) fn within(points: &[(f64, f64)], i: usize, eps: f64) -> bool {
    let (ti, ei) = points[i];
    if !(ti.is_finite() && ei.is_finite()) {
        return false;
    }
    let k = 1.0 - eps;
    !points
        .iter()
        .any(|&(t, e)| t.is_finite() && e.is_finite() && t <= k * ti && e <= k * ei)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn front_of_a_staircase() {
        let p = [(1.0, 5.0), (2.0, 3.0), (2.5, 4.0), (3.0, 1.0), (4.0, 1.0)];
        assert_eq!(front(&p), vec![0, 1, 3]);
        assert!(!within(&p, 2, 0.05));
        // (2.5, 4.0) is dominated by (2.0, 3.0) by more than 5% on both axes,
        // but within 25% of it.
        assert!(within(&p, 2, 0.25));
        assert!(
            within(&p, 4, 0.05),
            "equal error, slower: not 5% better in error"
        );
    }

    #[test]
    fn non_finite_points_are_never_on_the_front() {
        let p = [(1.0, f64::NAN), (2.0, 1.0), (f64::INFINITY, 0.0)];
        assert_eq!(front(&p), vec![1]);
        assert!(!within(&p, 0, 0.05));
    }

    proptest! {
        /// Front points are mutually non-dominated, every other point is
        /// dominated by (or equal to) a front point, and front points are within 5%.
        #[test]
        fn front_is_the_non_dominated_set(
            pts in proptest::collection::vec((0.1f64..100.0, 0.0f64..50.0), 1..40)
        ) {
            let f = front(&pts);
            prop_assert!(!f.is_empty());
            let dominates = |a: (f64, f64), b: (f64, f64)|
                a.0 <= b.0 && a.1 <= b.1 && (a.0 < b.0 || a.1 < b.1);
            for &i in &f {
                prop_assert!(within(&pts, i, 0.05));
                for &j in &f {
                    prop_assert!(!dominates(pts[j], pts[i]));
                }
            }
            for i in 0..pts.len() {
                if !f.contains(&i) {
                    prop_assert!(f.iter().any(|&j| dominates(pts[j], pts[i]) || pts[j] == pts[i]));
                }
            }
        }
    }
}
