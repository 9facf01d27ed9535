//! The camera's line of sight over the displaced surface, marched through
//! the DEM: whether a point that sees the camera below its local
//! horizontal (terrain past the sphere's limb that the DEM lifts into
//! view) does so over the relief nearer the limb. The horizon map cannot
//! say: it keeps no elevation below the horizontal.
//!
//! The march reads the surface the limb and the shading read
//! ([`crate::scene::surface::displaced_radius_tiled`]: the bilinear DEM
//! with its tiles), so the three agree.

use glam::DVec3;

use crate::scene::maps::EquirectMap;
use crate::scene::surface::displaced_radius_tiled;
use crate::scene::tile_surface::HeightTiles;

/// Most steps of one march: a DEM finer than this resolves over the
/// march's length is sampled at this many points.
pub const MAX_STEPS: usize = 4096;

/// The displaced surface a line of sight is marched over.
#[derive(Clone, Copy)]
pub struct Relief<'a> {
    /// Heights [m] of the global DEM.
    pub height: &'a EquirectMap,
    /// DEM tiles over it.
    pub tiles: Option<&'a HeightTiles>,
    /// The sphere's radius [m].
    pub radius: f64,
    /// Largest |height| [m] of the DEM and its tiles.
    pub bound: f64,
}

impl Relief<'_> {
    /// Half the finest DEM cell [rad] (latitude or longitude, of the
    /// global DEM or any tile): the march's step on the sphere.
    fn half_cell(&self) -> f64 {
        let global = (std::f64::consts::PI / self.height.height as f64)
            .min(std::f64::consts::TAU / self.height.width as f64);
        let tiles = self.tiles.map_or(f64::INFINITY, |t| {
            t.tiles()
                .tiles()
                .iter()
                .map(|tile| tile.grid.cell_lat().min(tile.grid.cell_lon()))
                .fold(f64::INFINITY, f64::min)
        });
        0.5 * global.min(tiles)
    }

    /// Whether the ray from the surface point `p` (body-fixed [m]) along
    /// the unit vector `v` leaves the relief's shell (radius R + bound)
    /// without passing under the surface r(n̂) = R + h(n̂). Samples every
    /// half DEM cell (at most [`MAX_STEPS`]) from one step off `p`; a ray
    /// whose closest approach passes under R − bound is blocked at once.
    pub fn clears(&self, p: DVec3, v: DVec3) -> bool {
        let top = self.radius + self.bound;
        let along = p.dot(v);
        let across_sq = p.length_squared() - along * along;
        if along < 0.0 {
            let low = (self.radius - self.bound).max(0.0);
            if across_sq < low * low {
                return false;
            }
        }
        let reach = top * top - across_sq;
        if reach <= 0.0 {
            return true;
        }
        let length = -along + reach.sqrt();
        if !(length > 0.0) {
            return true;
        }
        let step = self.half_cell() * self.radius;
        let n = ((length / step).ceil() as usize).clamp(1, MAX_STEPS);
        let dt = length / n as f64;
        (1..=n).all(|k| {
            let q = p + v * (k as f64 * dt);
            let r = q.length();
            r >= top || r >= displaced_radius_tiled(self.height, self.tiles, self.radius, q / r)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A flat DEM with one wall of height 50 m along a meridian band: a
    /// ray grazing the sphere past the limb clears the plain sphere, and
    /// is blocked when its path crosses the wall below the wall's top.
    #[test]
    fn a_wall_on_the_path_blocks_and_the_plain_sphere_does_not() {
        let (w, h) = (360, 180);
        let radius = 1000.0;
        let flat = EquirectMap::new(w, h, vec![0.0f32; w * h]);
        let mut data = vec![0.0f32; w * h];
        // Columns 180..=182: longitudes 0°..3° (cell centres 0.5°, 1.5°, 2.5°).
        for row in 0..h {
            for col in 180..=182 {
                data[row * w + col] = 50.0;
            }
        }
        let wall = EquirectMap::new(w, h, data);
        let relief = |m| Relief {
            height: m,
            tiles: None,
            radius,
            bound: 50.0,
        };
        // From 10 m above the equator at longitude −1° looking along +y
        // tilted down by 0.5°: the ray stays about 10 m above the sphere
        // (its drop and the sphere's sagitta nearly cancel over the 17 m
        // to the wall band) and meets the band below the wall's top.
        let lon = (-1.0f64).to_radians();
        let p = DVec3::new(lon.cos(), lon.sin(), 0.0) * (radius + 10.0);
        let east = DVec3::new(-lon.sin(), lon.cos(), 0.0);
        let up = p.normalize();
        let down = 0.5f64.to_radians();
        let v = (east * down.cos() - up * down.sin()).normalize();
        // The ray's height over the sphere where it meets the wall band:
        // the test's own geometry, for the claim above.
        let at_wall = (0..2000)
            .map(|k| p + v * (k as f64 * 0.1))
            .find(|q| q.y.atan2(q.x) >= 0.0)
            .unwrap();
        let height_there = at_wall.length() - radius;
        assert!(height_there > 0.0 && height_there < 50.0, "{height_there}");
        assert!(relief(&flat).clears(p, v));
        assert!(!relief(&wall).clears(p, v));
        // Looking up by 75°, the ray rises 63 m over the 17 m to the band:
        // it clears the wall's top (and the shell) before it.
        let rise = 75f64.to_radians();
        let steep = (east * rise.cos() + up * rise.sin()).normalize();
        assert!(relief(&wall).clears(p, steep));
        // Straight into the sphere: blocked at once.
        assert!(!relief(&flat).clears(p, -up));
    }
}
