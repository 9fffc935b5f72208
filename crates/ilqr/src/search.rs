//! Where to start a search over the ways around obstacles.
//!
//! iLQR is a local method: it returns the optimum nearest its initial
//! guess, and with obstacles the problem has one local optimum per way
//! around them. A search solves the problem from several starts and keeps
//! the best answer. This module says where those starts go: for each
//! obstacle near the straight segment from the initial position to the
//! goal's, one [`Detour`] on each side of it, a via-point beside the
//! obstacle at the knot where a constant-speed straight path would pass
//! it.
//!
//! A shooting method optimises controls, so a start must be controls. The
//! caller makes them with a short guiding solve: the problem's own cost
//! plus a [`ViaPath`](crate::ViaPath) term pulling every knot along the
//! route through the detour's via-point, from the plain initial guess. Its controls then start the real solve, which
//! settles into the local optimum on that side. (ALTRO's alternative, an
//! infeasible start with slack controls on the states, needs a model with
//! `NU + NX` controls; the guiding solve needs nothing from the model.)
//!
//! Limits: one obstacle at a time. With several obstacles in the way the
//! detours cover each obstacle's two sides, not every combination of sides
//! (2ⁿ routes for n obstacles); the plain start and the solves' own
//! freedom cover the rest as far as they do.

use nalgebra::Vector2;

use crate::constraint::{Region, Shape};

/// Which side of the straight path a detour passes an obstacle on, facing
/// from the initial position towards the goal.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Side {
    /// The obstacle on the right, the path to its left.
    Left,
    /// The obstacle on the left, the path to its right.
    Right,
}

/// An obstacle as the search sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Obstacle {
    /// What it occupies.
    pub region: Region,
    /// How far from the region's boundary (m) a path that passes it is
    /// expected to keep: its clearance, plus the reach of a soft cost. The
    /// via-point is this far out, and the obstacle is in the way when the
    /// straight path comes closer than this. One that is not finite puts
    /// the obstacle out of the way (no detours).
    pub margin: f64,
}

/// A start that passes one obstacle on one side.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Detour {
    /// The obstacle's index in the slice given to [`detours`].
    pub obstacle: usize,
    /// The side of the straight path.
    pub side: Side,
    /// The obstacle's centre, m.
    pub center: Vector2<f64>,
    /// The via-point, m.
    pub via: Vector2<f64>,
    /// The unit vector from the obstacle's centre towards the via-point.
    pub direction: Vector2<f64>,
    /// The unit vector along the straight path, towards the goal.
    pub along: Vector2<f64>,
    /// The stage at which the guiding solve pulls the position to `via`
    /// (`1 ≤ knot < N`).
    pub knot: usize,
    /// The smallest signed distance (m) from the straight path to the
    /// obstacle's region: how much in the way it is (negative: the path
    /// crosses it).
    pub gap: f64,
}

/// The detours around the obstacles in the way of the straight path from
/// `start` to `goal` over `horizon` steps: two per obstacle (left, then
/// right), the obstacles ordered from the most in the way (smallest gap,
/// then lowest index). None when the horizon has fewer than 2 steps or the
/// start is at the goal (no straight path to leave).
pub fn detours(
    start: Vector2<f64>,
    goal: Vector2<f64>,
    horizon: usize,
    obstacles: &[Obstacle],
) -> Vec<Detour> {
    let path = goal - start;
    let length = path.norm();
    if horizon < 2 || !(length > 0.0 && length.is_finite()) {
        return Vec::new();
    }
    let along = path / length;
    // Facing along the path, the left is a quarter turn counter-clockwise.
    let left = Vector2::new(-along.y, along.x);
    let mut found: Vec<(f64, usize)> = obstacles
        .iter()
        .enumerate()
        .filter_map(|(j, o)| {
            let gap = segment_distance(&o.region, start, goal);
            (gap < o.margin && o.margin.is_finite()).then_some((gap, j))
        })
        .collect();
    found.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let mut out = Vec::with_capacity(2 * found.len());
    for (gap, j) in found {
        let o = &obstacles[j];
        let c = o.region.center;
        let t = ((c - start).dot(&along) / length).clamp(0.0, 1.0);
        let knot = ((t * horizon as f64).round() as usize).clamp(1, horizon - 1);
        for (side, n) in [(Side::Left, left), (Side::Right, -left)] {
            // Beside the obstacle, measured from where the straight path
            // passes its centre: a centre off the path still gets a via-point
            // on each side of the region itself.
            let out_by = extent(&o.region.shape, &n) + o.margin;
            out.push(Detour {
                obstacle: j,
                side,
                center: c,
                via: c + n * out_by,
                direction: n,
                along,
                knot,
                gap,
            });
        }
    }
    out
}

impl Detour {
    /// Whether `path` (positions, m) already passes the obstacle on this
    /// detour's side: where it crosses the line through the obstacle's
    /// centre across the straight path, it lies beyond the centre along
    /// [`Detour::direction`]. Of several crossings (a path that loops), the
    /// one nearest the centre counts; a path that never crosses is judged
    /// where it comes nearest the centre. A path through the centre, or one
    /// with a position that is not finite, passes on neither side.
    ///
    /// Nearness alone misjudges a start beside the obstacle: the first
    /// position is then the nearest, on whichever side the start is,
    /// wherever the path goes after.
    pub fn is_taken_by(&self, path: impl IntoIterator<Item = Vector2<f64>>) -> bool {
        self.side_of(path) == Some(self.side)
    }

    /// The side of the straight path on which `path` passes the obstacle,
    /// as [`Detour::is_taken_by`] judges it; `None` through the centre, or
    /// with a position that is not finite.
    pub fn side_of(&self, path: impl IntoIterator<Item = Vector2<f64>>) -> Option<Side> {
        let mut crossing: Option<f64> = None;
        let mut nearest: Option<(f64, f64)> = None;
        let mut previous: Option<(f64, f64)> = None;
        for p in path {
            let d = p - self.center;
            if !(d.x.is_finite() && d.y.is_finite()) {
                return None;
            }
            // Along the straight path, and towards this detour's side.
            let (s, l) = (d.dot(&self.along), d.dot(&self.direction));
            if let Some((s0, l0)) = previous
                && (s0 <= 0.0) != (s <= 0.0)
            {
                let lateral = l0 + (l - l0) * (s0 / (s0 - s));
                if crossing.is_none_or(|c| lateral.abs() < c.abs()) {
                    crossing = Some(lateral);
                }
            }
            previous = Some((s, l));
            let r = d.norm_squared();
            if nearest.is_none_or(|(best, _)| r < best) {
                nearest = Some((r, l));
            }
        }
        let other = match self.side {
            Side::Left => Side::Right,
            Side::Right => Side::Left,
        };
        match crossing.or(nearest.map(|(_, l)| l)) {
            Some(l) if l > 0.0 => Some(self.side),
            Some(l) if l < 0.0 => Some(other),
            _ => None,
        }
    }
}

/// How far the region reaches from its centre along the unit vector `n`.
fn extent(shape: &Shape, n: &Vector2<f64>) -> f64 {
    match *shape {
        Shape::Point => 0.0,
        Shape::Circle { radius } => radius,
        Shape::Rectangle(r) => {
            let ((a, b), size) = (r.axes(), r.size());
            n.dot(&a).abs() * size.x / 2.0 + n.dot(&b).abs() * size.y / 2.0
        }
    }
}

/// The smallest signed distance from the segment `a`–`b` to `region`. The
/// signed distance to a convex region is convex along a line, so a
/// golden-section search finds its minimum over the segment.
fn segment_distance(region: &Region, a: Vector2<f64>, b: Vector2<f64>) -> f64 {
    let at = |t: f64| region.signed_distance(&(a + (b - a) * t));
    let ratio = (5f64.sqrt() - 1.0) / 2.0;
    let (mut lo, mut hi) = (0.0f64, 1.0f64);
    let (mut x1, mut x2) = (hi - ratio * (hi - lo), lo + ratio * (hi - lo));
    let (mut f1, mut f2) = (at(x1), at(x2));
    // 60 steps shrink the interval by 0.618⁶⁰ ≈ 3e-13 of the segment.
    for _ in 0..60 {
        if f1 <= f2 {
            hi = x2;
            (x2, f2) = (x1, f1);
            x1 = hi - ratio * (hi - lo);
            f1 = at(x1);
        } else {
            lo = x1;
            (x1, f1) = (x2, f2);
            x2 = lo + ratio * (hi - lo);
            f2 = at(x2);
        }
    }
    f1.min(f2).min(at(0.0)).min(at(1.0))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::constraint::Rectangle;

    fn circle(x: f64, y: f64, radius: f64, margin: f64) -> Obstacle {
        Obstacle {
            region: Region {
                center: Vector2::new(x, y),
                shape: Shape::Circle { radius },
            },
            margin,
        }
    }

    /// The seed: from (5, 0) to (4, 9) past a point at (4.5, 4.5), on the
    /// path's midpoint. Left of a path heading north is west.
    #[test]
    fn an_obstacle_on_the_path_gets_a_detour_each_side_at_its_knot() {
        let o = Obstacle {
            region: Region {
                center: Vector2::new(4.5, 4.5),
                shape: Shape::Point,
            },
            margin: 3.0,
        };
        let d = detours(Vector2::new(5.0, 0.0), Vector2::new(4.0, 9.0), 100, &[o]);
        assert_eq!(d.len(), 2);
        assert_eq!((d[0].side, d[1].side), (Side::Left, Side::Right));
        assert!(d[0].via.x < 4.5 - 2.9 && d[1].via.x > 4.5 + 2.9, "{d:?}");
        for x in &d {
            assert_eq!(x.knot, 50);
            assert!(x.gap.abs() < 1e-9, "{}", x.gap);
            assert!(((x.via - o.region.center).norm() - 3.0).abs() < 1e-12);
        }
    }

    /// Obstacles out of reach get none; the rest are ordered from the
    /// most in the way, and a circle's via-point clears its radius.
    #[test]
    fn only_obstacles_in_the_way_count_most_in_the_way_first() {
        let obstacles = [
            circle(5.0, 3.0, 1.0, 1.0),  // 2 m off the x axis, gap 2 > 1
            circle(3.0, 1.5, 1.0, 1.0),  // gap 0.5
            circle(7.0, -0.5, 1.0, 1.0), // gap −0.5: crossed
        ];
        let d = detours(Vector2::zeros(), Vector2::new(10.0, 0.0), 10, &obstacles);
        let order: Vec<_> = d.iter().map(|x| (x.obstacle, x.side)).collect();
        assert_eq!(
            order,
            [
                (2, Side::Left),
                (2, Side::Right),
                (1, Side::Left),
                (1, Side::Right)
            ]
        );
        assert!((d[0].gap + 0.5).abs() < 1e-9 && (d[2].gap - 0.5).abs() < 1e-9);
        assert_eq!(d[0].via, Vector2::new(7.0, 1.5));
        assert_eq!(d[1].via, Vector2::new(7.0, -2.5));
        assert_eq!((d[0].knot, d[2].knot), (7, 3));
    }

    /// A turned rectangle reaches along the normal by its projection; the
    /// segment's distance to it is found between the ends.
    #[test]
    fn a_rectangle_reaches_by_its_projection() {
        let o = Obstacle {
            region: Region {
                center: Vector2::new(5.0, 0.0),
                shape: Shape::Rectangle(Rectangle::new(
                    Vector2::new(2.0, 4.0),
                    std::f64::consts::FRAC_PI_2,
                )),
            },
            margin: 0.5,
        };
        let d = detours(Vector2::zeros(), Vector2::new(10.0, 0.0), 20, &[o]);
        // Turned a quarter, its 2 m width lies along y: 1 m out, plus 0.5.
        assert!((d[0].via - Vector2::new(5.0, 1.5)).norm() < 1e-12, "{d:?}");
        assert!((d[0].gap + 1.0).abs() < 1e-9, "{}", d[0].gap);
    }

    /// A path is on a detour's side where it comes nearest the centre,
    /// wherever else it goes; one through the centre, or not finite, is on
    /// neither.
    #[test]
    fn a_path_takes_the_side_it_passes_nearest_the_centre_on() {
        let o = circle(5.0, 0.0, 1.0, 1.0);
        let d = detours(Vector2::zeros(), Vector2::new(10.0, 0.0), 10, &[o]);
        let (left, right) = (&d[0], &d[1]);
        // Along the x axis the left is north. This path starts south of
        // the axis and bends north, 2 m up, as it passes x = 5.
        let north: Vec<_> = (0..=10)
            .map(|k| {
                let x = k as f64;
                Vector2::new(x, 2.0 - 0.5 * (x - 5.0).powi(2))
            })
            .collect();
        assert!(north[0].y < 0.0);
        assert!(left.is_taken_by(north.iter().copied()));
        assert!(!right.is_taken_by(north.iter().copied()));
        let mirrored = north.iter().map(|p| Vector2::new(p.x, -p.y));
        assert!(right.is_taken_by(mirrored.clone()) && !left.is_taken_by(mirrored));
        let through = (0..=10).map(|k| Vector2::new(k as f64, 0.0));
        assert!(!left.is_taken_by(through.clone()) && !right.is_taken_by(through));
        let broken = [Vector2::new(5.0, 1.0), Vector2::new(f64::NAN, 0.0)];
        assert!(!left.is_taken_by(broken));
        assert!(!left.is_taken_by([]));
    }

    /// A start beside the obstacle is the path's nearest point, but not
    /// where it passes: case 4b of issue 40, a start 2.1 m south-south-east
    /// of a soft obstacle and a path that swings 3 m west of it.
    #[test]
    // 0.318 is the number, not 1/π.
    #[allow(clippy::approx_constant)]
    fn a_start_beside_the_obstacle_does_not_decide_the_side() {
        let o = circle(0.461, 2.433, 0.0, 3.5);
        let (start, goal) = (Vector2::new(0.164, 0.318), Vector2::new(1.954, 6.492));
        let d = detours(start, goal, 100, &[o]);
        let (west, east) = (&d[0], &d[1]);
        assert!(west.direction.x < 0.0 && east.direction.x > 0.0);
        // Round the west of the obstacle: out to x = -2.7 at its height.
        let path: Vec<_> = (0..=20)
            .map(|k| {
                let t = f64::from(k) / 20.0;
                let bulge = -3.0 * (std::f64::consts::PI * t).sin();
                start + (goal - start) * t + Vector2::new(bulge, 0.0)
            })
            .collect();
        assert!((path[0] - o.region.center).norm() < (path[10] - o.region.center).norm());
        assert!(west.is_taken_by(path.iter().copied()));
        assert!(!east.is_taken_by(path.iter().copied()));
    }

    #[test]
    fn no_detours_without_a_path_to_leave() {
        let o = [circle(0.0, 0.0, 1.0, 1.0)];
        assert!(detours(Vector2::zeros(), Vector2::zeros(), 10, &o).is_empty());
        assert!(detours(Vector2::zeros(), Vector2::new(1.0, 0.0), 1, &o).is_empty());
        let nan = Vector2::new(f64::NAN, 0.0);
        assert!(detours(Vector2::zeros(), nan, 10, &o).is_empty());
    }
}
