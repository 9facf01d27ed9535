//! Identification of the detected dots: which grid dot each one is.
//!
//! The anchor dots, each shown alone in its own frame, are identified by
//! construction (the frame's one plausible blob, when it is unambiguous);
//! they fix a first homography, checked for consistency by dropping the
//! worst anchor while it disagrees. Every grid dot's direction is then
//! predicted and matched to the nearest detection within a gate (a fraction
//! of the predicted distance to the neighbouring dots), one detection per
//! dot, nearest pairs first. Missing dots leave their prediction unmatched;
//! spurious blobs fall outside every gate. The caller refits the full model
//! on the matches and matches again with its better predictions, over a
//! region of the screen that grows from the anchors (a homography
//! extrapolated far beyond them could be off by a whole dot).

use super::fit::{apply_homography, homography, normalise};
use super::patterns::DotGrid;
use crate::error::{Error, Result};

/// An anchor dot: its grid index and the direction it was seen at.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AnchorSighting {
    pub dot: usize,
    pub tan: [f64; 2],
}

/// The first homography (normalised screen → tangent) from the anchors,
/// by consensus: of the homographies through every four anchors, the one
/// that the most anchors agree with (within `gate` times the local dot
/// spacing), refitted to those anchors. A misidentified anchor (a
/// reflection taken for the dot) is thus left out. Errors when fewer than
/// four anchors agree.
pub fn anchor_homography(
    grid: &DotGrid,
    anchors: &[AnchorSighting],
    shown: usize,
    gate: f64,
) -> Result<[f64; 8]> {
    let too_few = |n: usize| {
        Error::Other(format!(
            "geometric calibration: only {n} of {shown} anchor dots were identified \
             consistently (at least 4 needed): check that the camera sees the centre \
             of the screen, the exposure and the dot level"
        ))
    };
    if anchors.len() < 4 {
        return Err(too_few(anchors.len()));
    }
    let s: Vec<[f64; 2]> = anchors
        .iter()
        .map(|a| {
            let c = grid.centres[a.dot];
            normalise(grid.screen, c[0], c[1])
        })
        .collect();
    let t: Vec<[f64; 2]> = anchors.iter().map(|a| a.tan).collect();
    let agreeing = |h: &[f64; 8]| -> Vec<usize> {
        let predict = |u: f64, v: f64| apply_homography(h, normalise(grid.screen, u, v));
        (0..anchors.len())
            .filter(|&i| {
                let c = grid.centres[anchors[i].dot];
                let p = predict(c[0], c[1]);
                let miss = (p[0] - t[i][0]).hypot(p[1] - t[i][1]);
                miss <= gate * local_spacing(&predict, grid, c)
            })
            .collect()
    };
    let n = anchors.len();
    let mut best: Vec<usize> = Vec::new();
    for a in 0..n {
        for b in a + 1..n {
            for c in b + 1..n {
                for d in c + 1..n {
                    let q = [a, b, c, d];
                    let sq: Vec<[f64; 2]> = q.iter().map(|&i| s[i]).collect();
                    let tq: Vec<[f64; 2]> = q.iter().map(|&i| t[i]).collect();
                    if let Some(h) = homography(&sq, &tq) {
                        let agree = agreeing(&h);
                        if agree.len() > best.len() {
                            best = agree;
                        }
                    }
                }
            }
        }
    }
    if best.len() < 4 {
        return Err(too_few(best.len()));
    }
    let sb: Vec<[f64; 2]> = best.iter().map(|&i| s[i]).collect();
    let tb: Vec<[f64; 2]> = best.iter().map(|&i| t[i]).collect();
    homography(&sb, &tb).ok_or_else(|| too_few(0))
}

/// Distance, in the predicted directions, from the dot at `c` to its
/// nearer neighbour along u or v.
pub fn local_spacing(predict: &impl Fn(f64, f64) -> [f64; 2], grid: &DotGrid, c: [f64; 2]) -> f64 {
    let p = predict(c[0], c[1]);
    let pu = predict(c[0] + grid.spacing, c[1]);
    let pv = predict(c[0], c[1] + grid.spacing);
    (pu[0] - p[0])
        .hypot(pu[1] - p[1])
        .min((pv[0] - p[0]).hypot(pv[1] - p[1]))
}

/// For each grid dot marked `active`, the index of the detection matched
/// to it: the nearest within `gate` × the local spacing of the
/// predictions, each detection used once (closest pairs first).
pub fn match_dots(
    grid: &DotGrid,
    predict: &impl Fn(f64, f64) -> [f64; 2],
    detections: &[[f64; 2]],
    gate: f64,
    active: &[bool],
) -> Vec<Option<usize>> {
    let mut pairs: Vec<(f64, usize, usize)> = Vec::new();
    for (dot, c) in grid.centres.iter().enumerate() {
        if !active[dot] {
            continue;
        }
        let p = predict(c[0], c[1]);
        let radius = gate * local_spacing(predict, grid, *c);
        for (k, d) in detections.iter().enumerate() {
            let dist = (d[0] - p[0]).hypot(d[1] - p[1]);
            if dist <= radius {
                pairs.push((dist, dot, k));
            }
        }
    }
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut of_dot = vec![None; grid.centres.len()];
    let mut used = vec![false; detections.len()];
    for (_, dot, k) in pairs {
        if of_dot[dot].is_none() && !used[k] {
            of_dot[dot] = Some(k);
            used[k] = true;
        }
    }
    of_dot
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::geometric::patterns::DotShape;

    fn grid() -> DotGrid {
        DotGrid::new((640, 480), 64, 4.0, DotShape::Gaussian, 255, 8)
    }

    /// A rotated, scaled view: the test's own map.
    fn view(u: f64, v: f64) -> [f64; 2] {
        let (x, y) = ((u - 320.0) * 1e-4, (v - 240.0) * 1e-4);
        [0.999 * x - 0.04 * y, 0.04 * x + 0.999 * y]
    }

    #[test]
    fn a_wrong_anchor_is_dropped() {
        let g = grid();
        let mut anchors: Vec<AnchorSighting> = g
            .anchors()
            .into_iter()
            .map(|dot| {
                let c = g.centres[dot];
                AnchorSighting {
                    dot,
                    tan: view(c[0], c[1]),
                }
            })
            .collect();
        // The third anchor was really its neighbour.
        let c = g.centres[anchors[2].dot + 1];
        anchors[2].tan = view(c[0], c[1]);
        let h = anchor_homography(&g, &anchors, 9, 0.3).unwrap();
        for c in &g.centres {
            let (p, t) = (
                apply_homography(&h, normalise(g.screen, c[0], c[1])),
                view(c[0], c[1]),
            );
            assert!((p[0] - t[0]).hypot(p[1] - t[1]) < 1e-12, "{p:?} {t:?}");
        }
        let e = anchor_homography(&g, &anchors[..3], 9, 0.3)
            .unwrap_err()
            .to_string();
        assert!(e.contains("only 3 of 9 anchor dots"), "{e}");
        // The first row's three anchors and one more: three collinear
        // points fix no homography.
        let e = anchor_homography(&g, &anchors[..4], 9, 0.3)
            .unwrap_err()
            .to_string();
        assert!(e.contains("of 9 anchor dots"), "{e}");
    }

    #[test]
    fn matching_skips_missing_and_spurious_dots() {
        let g = grid();
        let mut det: Vec<[f64; 2]> = Vec::new();
        let mut truth = Vec::new();
        for (i, c) in g.centres.iter().enumerate() {
            if i % 7 == 3 {
                truth.push(None);
                continue;
            }
            truth.push(Some(det.len()));
            let t = view(c[0], c[1]);
            det.push([t[0] + 1e-6, t[1] - 1e-6]);
        }
        // Spurious: half-way between two dots, and far outside.
        let (a, b) = (view(32.0, 48.0), view(96.0, 48.0));
        det.push([(a[0] + b[0]) / 2.0, (a[1] + b[1]) / 2.0]);
        det.push([0.5, 0.5]);
        assert_eq!(
            match_dots(&g, &view, &det, 0.3, &vec![true; g.centres.len()]),
            truth
        );
        // Inactive dots are not matched.
        let mut active = vec![true; g.centres.len()];
        active[0] = false;
        assert_eq!(match_dots(&g, &view, &det, 0.3, &active)[0], None);
    }
}
