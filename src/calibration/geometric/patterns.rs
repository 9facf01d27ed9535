//! The dot patterns shown on the screen: the full grid of dots at known
//! screen positions, the sparse anchor dots shown one per frame to identify
//! the grid, and their drawing into a frame buffer.

use crate::facility::lut::encode_grey;

/// How a dot's drive level falls off from its centre.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum DotShape {
    /// Gaussian of standard deviation `radius_px` (cut at 4 σ): smooth, so
    /// its camera image has no aliasing and its centroid no bias.
    Gaussian,
    /// Uniform disc of radius `radius_px`.
    Disc,
}

/// A regular grid of dots on the screen.
#[derive(Debug, Clone, PartialEq)]
pub struct DotGrid {
    /// Screen size `(w, h)`, pixels.
    pub screen: (usize, usize),
    /// Distance between neighbouring dots, screen pixels.
    pub spacing: f64,
    /// Dot radius (Gaussian σ or disc radius), screen pixels.
    pub radius: f64,
    pub shape: DotShape,
    /// Peak drive level.
    pub level: u32,
    /// Drive bits (8 or 10).
    pub bits: u32,
    /// Dot centres, continuous screen pixel coordinates, row-major.
    pub centres: Vec<[f64; 2]>,
    /// Columns and rows of the grid.
    pub cols: usize,
    pub rows: usize,
}

impl DotGrid {
    /// Dots every `spacing` pixels, centred on the screen so the margins at
    /// both ends are equal and at least half a spacing.
    pub fn new(
        screen: (usize, usize),
        spacing: usize,
        radius: f64,
        shape: DotShape,
        level: u32,
        bits: u32,
    ) -> DotGrid {
        let axis = |size: usize| -> Vec<f64> {
            let n = (size / spacing).max(1);
            let start = (size as f64 - (n - 1) as f64 * spacing as f64) / 2.0;
            (0..n).map(|k| start + (k * spacing) as f64).collect()
        };
        let (us, vs) = (axis(screen.0), axis(screen.1));
        let centres = vs
            .iter()
            .flat_map(|&v| us.iter().map(move |&u| [u, v]))
            .collect();
        DotGrid {
            screen,
            spacing: spacing as f64,
            radius,
            shape,
            level,
            bits,
            centres,
            cols: us.len(),
            rows: vs.len(),
        }
    }

    /// Indices of the anchor dots: a 3 × 3 block of grid dots around the
    /// dot nearest the screen centre, `anchor_step` dots apart (an eighth
    /// of the shorter grid side, at least one): near the centre, because
    /// the collimator's axis is there and a camera whose field is smaller
    /// than the screen still sees them; spread enough to fix a homography.
    /// Fewer near a grid too small for nine distinct dots.
    pub fn anchors(&self) -> Vec<usize> {
        let step = self.anchor_step() as isize;
        let (c0, r0) = ((self.cols / 2) as isize, (self.rows / 2) as isize);
        let mut out: Vec<usize> = Vec::new();
        for dr in [-step, 0, step] {
            for dc in [-step, 0, step] {
                let col = (c0 + dc).clamp(0, self.cols as isize - 1) as usize;
                let row = (r0 + dr).clamp(0, self.rows as isize - 1) as usize;
                let k = row * self.cols + col;
                if !out.contains(&k) {
                    out.push(k);
                }
            }
        }
        out
    }

    /// Dots between neighbouring anchors.
    pub fn anchor_step(&self) -> usize {
        ((self.cols.min(self.rows) as f64 / 8.0).round() as usize).max(1)
    }

    /// A black frame (`w × h` pixels `0x00RRGGBB`) with the dots `which`.
    pub fn draw(&self, which: impl IntoIterator<Item = usize>) -> Vec<u32> {
        let (w, h) = self.screen;
        let mut levels = vec![0u32; w * h];
        let reach = match self.shape {
            DotShape::Gaussian => 4.0 * self.radius,
            DotShape::Disc => self.radius + 1.0,
        };
        for k in which {
            let [cu, cv] = self.centres[k];
            let x0 = (cu - reach).floor().max(0.0) as usize;
            let y0 = (cv - reach).floor().max(0.0) as usize;
            let x1 = ((cu + reach).ceil() as usize).min(w);
            let y1 = ((cv + reach).ceil() as usize).min(h);
            for y in y0..y1 {
                for x in x0..x1 {
                    let (dx, dy) = (x as f64 + 0.5 - cu, y as f64 + 0.5 - cv);
                    let l = (self.profile(dx, dy) * self.level as f64).round() as u32;
                    let p = &mut levels[y * w + x];
                    *p = (*p).max(l);
                }
            }
        }
        levels
            .into_iter()
            .map(|l| encode_grey(l, self.bits))
            .collect()
    }

    /// Relative drive (0..1) at offset `(dx, dy)` from a dot centre.
    fn profile(&self, dx: f64, dy: f64) -> f64 {
        let r2 = dx * dx + dy * dy;
        match self.shape {
            DotShape::Gaussian => {
                let s2 = self.radius * self.radius;
                if r2 > 16.0 * s2 {
                    0.0
                } else {
                    (-0.5 * r2 / s2).exp()
                }
            }
            DotShape::Disc => disc_coverage(r2.sqrt(), self.radius),
        }
    }
}

/// Fraction of a pixel at distance `r` from the centre covered by a disc of
/// radius `radius` (a one-pixel linear ramp across the edge: antialiased,
/// so the drawn disc's centroid is its centre to a small fraction of a
/// pixel).
fn disc_coverage(r: f64, radius: f64) -> f64 {
    (radius + 0.5 - r).clamp(0.0, 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::facility::lut::decode_grey;

    #[test]
    fn grid_is_centred_and_dots_peak_at_their_centres() {
        let g = DotGrid::new((200, 100), 40, 2.0, DotShape::Gaussian, 200, 8);
        assert_eq!((g.cols, g.rows), (5, 2));
        // Equal margins: 20 px each side along u, 30 along v.
        assert_eq!(g.centres[0], [20.0, 30.0]);
        assert_eq!(g.centres[9], [180.0, 70.0]);
        let f = g.draw([0usize]);
        // Pixel (19,29) and (20,30) touch the centre (20, 30): both at
        // 0.5 px diagonal offset, exp(-0.25/4)·200 = 188.
        let at = |x: usize, y: usize| decode_grey(f[y * 200 + x], 8);
        assert_eq!(at(19, 29), 188);
        assert_eq!(at(20, 30), 188);
        assert_eq!(at(60, 30), 0);
        // Grey: R = G = B.
        assert_eq!(f[29 * 200 + 19], 188 << 16 | 188 << 8 | 188);
    }

    #[test]
    fn anchors_are_distinct_grid_dots() {
        let g = DotGrid::new((1920, 1080), 64, 3.0, DotShape::Disc, 255, 8);
        let a = g.anchors();
        assert_eq!(a.len(), 9);
        let centre = g.centres[a[4]];
        assert!((centre[0] - 960.0).abs() <= 64.0 && (centre[1] - 540.0).abs() <= 64.0);
        // 30 × 16 dots: anchors 2 dots (128 px) apart.
        assert_eq!(g.anchor_step(), 2);
        let corner = g.centres[a[0]];
        assert_eq!(
            [centre[0] - corner[0], centre[1] - corner[1]],
            [128.0, 128.0]
        );
        // A tiny grid still gives distinct anchors.
        let tiny = DotGrid::new((64, 32), 32, 2.0, DotShape::Disc, 255, 8);
        assert_eq!(tiny.anchors().len(), 2);
    }
}
