//! Solid primitives (capsules, ellipsoids, boxes): distance queries for collisions and
//! surface following, and triangle meshes for rendering.

use glam::{DMat3, DVec3};

use crate::math::{cos, sin};

/// A solid primitive.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Shape {
    /// All points within `r` of the segment `a`-`b`.
    Capsule { a: DVec3, b: DVec3, r: f64 },
    /// Centre, orientation (columns = local axes), semi-axes.
    Ellipsoid { c: DVec3, rot: DMat3, radii: DVec3 },
    /// Centre, orientation, half extents.
    Box { c: DVec3, rot: DMat3, half: DVec3 },
}

impl Shape {
    /// Signed distance (negative inside). Exact for capsules and boxes; a lower bound for
    /// ellipsoids, which is what sphere tracing and collision push-out need.
    pub fn sdf(&self, p: DVec3) -> f64 {
        match *self {
            Shape::Capsule { a, b, r } => {
                let ab = b - a;
                let t = ((p - a).dot(ab) / ab.length_squared().max(1e-12)).clamp(0.0, 1.0);
                (p - (a + t * ab)).length() - r
            }
            Shape::Ellipsoid { c, rot, radii } => {
                let q = (rot.transpose() * (p - c)) / radii;
                (q.length() - 1.0) * radii.min_element()
            }
            Shape::Box { c, rot, half } => {
                let q = (rot.transpose() * (p - c)).abs() - half;
                q.max(DVec3::ZERO).length() + q.max_element().min(0.0)
            }
        }
    }

    /// The point pushed out to `margin` outside the surface if it is closer, with the
    /// outward normal; `None` if it is already far enough.
    pub fn push_out(&self, p: DVec3, margin: f64) -> Option<(DVec3, DVec3)> {
        match *self {
            Shape::Capsule { a, b, r } => {
                let ab = b - a;
                let t = ((p - a).dot(ab) / ab.length_squared().max(1e-12)).clamp(0.0, 1.0);
                let axis = a + t * ab;
                let d = p - axis;
                let len = d.length();
                if len >= r + margin {
                    return None;
                }
                let n = if len > 1e-9 { d / len } else { DVec3::Z };
                Some((axis + n * (r + margin), n))
            }
            Shape::Ellipsoid { c, rot, radii } => {
                let grown = radii + DVec3::splat(margin);
                let local = rot.transpose() * (p - c);
                let q = local / grown;
                let len = q.length();
                if len >= 1.0 {
                    return None;
                }
                let q = if len > 1e-9 { q / len } else { DVec3::Z };
                let surface = q * grown;
                let n = (rot * (surface / (grown * grown))).normalize();
                Some((c + rot * surface, n))
            }
            Shape::Box { c, rot, half } => {
                let local = rot.transpose() * (p - c);
                let grown = half + DVec3::splat(margin);
                let gap = grown - local.abs();
                if gap.min_element() <= 0.0 {
                    return None;
                }
                // Leave through the nearest face.
                let axis = if gap.x <= gap.y && gap.x <= gap.z {
                    0
                } else if gap.y <= gap.z {
                    1
                } else {
                    2
                };
                let mut out = local;
                let sign = if local[axis] >= 0.0 { 1.0 } else { -1.0 };
                out[axis] = sign * grown[axis];
                let mut n = DVec3::ZERO;
                n[axis] = sign;
                Some((c + rot * out, rot * n))
            }
        }
    }
}

/// Distance to the union of `shapes`.
pub fn union_sdf(shapes: &[Shape], p: DVec3) -> f64 {
    shapes
        .iter()
        .map(|s| s.sdf(p))
        .fold(f64::INFINITY, f64::min)
}

/// Height of the highest surface of `shapes` below `top` at (x, y), by sphere tracing
/// straight down; `None` if the vertical line misses them all.
pub fn surface_height(shapes: &[Shape], x: f64, y: f64, top: f64, bottom: f64) -> Option<f64> {
    let mut z = top;
    for _ in 0..200 {
        let d = union_sdf(shapes, DVec3::new(x, y, z));
        if d < 2e-4 {
            return Some(z);
        }
        z -= d.max(1e-4);
        if z < bottom {
            return None;
        }
    }
    Some(z)
}

/// A triangle mesh with one colour and an object id (for the renderer's id buffer).
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    pub positions: Vec<DVec3>,
    pub normals: Vec<DVec3>,
    pub indices: Vec<[u32; 3]>,
}

impl Mesh {
    fn push_vertex(&mut self, p: DVec3, n: DVec3) -> u32 {
        self.positions.push(p);
        self.normals.push(n);
        (self.positions.len() - 1) as u32
    }

    /// Appends another mesh.
    pub fn extend(&mut self, other: &Mesh) {
        let base = self.positions.len() as u32;
        self.positions.extend_from_slice(&other.positions);
        self.normals.extend_from_slice(&other.normals);
        self.indices.extend(
            other
                .indices
                .iter()
                .map(|t| [t[0] + base, t[1] + base, t[2] + base]),
        );
    }

    /// A closed mesh of a shape; `detail` = segments around.
    pub fn of(shape: &Shape, detail: usize) -> Mesh {
        match *shape {
            Shape::Ellipsoid { c, rot, radii } => {
                let mut m = Mesh::default();
                let (seg, rings) = (detail.max(6), (detail / 2).max(4));
                for i in 0..=rings {
                    let v = std::f64::consts::PI * i as f64 / rings as f64;
                    for j in 0..=seg {
                        let u = std::f64::consts::TAU * j as f64 / seg as f64;
                        let unit = DVec3::new(sin(v) * cos(u), sin(v) * sin(u), cos(v));
                        let p = c + rot * (unit * radii);
                        let n = (rot * (unit / radii)).normalize();
                        m.push_vertex(p, n);
                    }
                }
                grid_indices(&mut m, rings, seg);
                m
            }
            Shape::Capsule { a, b, r } => {
                let axis = b - a;
                let len = axis.length().max(1e-9);
                let w = axis / len;
                // (v, u, w) is left-handed for glam's pair, which makes the grid face outwards.
                let (v, u) = w.any_orthonormal_pair();
                let mut m = Mesh::default();
                let seg = detail.max(6);
                let cap_rings = (detail / 4).max(2);
                // Rings from the a-end pole to the b-end pole.
                let mut rings: Vec<(f64, f64)> = Vec::new(); // (offset along axis, radius scale)
                for i in 0..=cap_rings {
                    let ang = std::f64::consts::FRAC_PI_2 * (1.0 - i as f64 / cap_rings as f64);
                    rings.push((-sin(ang) * r, cos(ang)));
                }
                for i in 0..=cap_rings {
                    let ang = std::f64::consts::FRAC_PI_2 * i as f64 / cap_rings as f64;
                    rings.push((len + sin(ang) * r, cos(ang)));
                }
                for &(off, scale) in &rings {
                    let base = a + w * off;
                    let axial = if off < 0.0 {
                        -(1.0 - scale * scale).max(0.0).sqrt()
                    } else if off > len {
                        (1.0 - scale * scale).max(0.0).sqrt()
                    } else {
                        0.0
                    };
                    for j in 0..=seg {
                        let t = std::f64::consts::TAU * j as f64 / seg as f64;
                        let radial = u * cos(t) + v * sin(t);
                        let n = (radial * scale + w * axial).normalize_or_zero();
                        m.push_vertex(base + radial * r * scale, n);
                    }
                }
                grid_indices(&mut m, rings.len() - 1, seg);
                m
            }
            Shape::Box { c, rot, half } => {
                let mut m = Mesh::default();
                for axis in 0..3 {
                    for sign in [-1.0, 1.0] {
                        let mut n = DVec3::ZERO;
                        n[axis] = sign;
                        let (a1, a2) = ((axis + 1) % 3, (axis + 2) % 3);
                        let corner = |s1: f64, s2: f64| {
                            let mut p = DVec3::ZERO;
                            p[axis] = sign * half[axis];
                            p[a1] = s1 * half[a1];
                            p[a2] = s2 * half[a2];
                            c + rot * p
                        };
                        let nn = rot * n;
                        let i0 = m.push_vertex(corner(-1.0, -1.0), nn);
                        let i1 = m.push_vertex(corner(1.0, -1.0), nn);
                        let i2 = m.push_vertex(corner(1.0, 1.0), nn);
                        let i3 = m.push_vertex(corner(-1.0, 1.0), nn);
                        if sign > 0.0 {
                            m.indices.push([i0, i1, i2]);
                            m.indices.push([i0, i2, i3]);
                        } else {
                            m.indices.push([i0, i2, i1]);
                            m.indices.push([i0, i3, i2]);
                        }
                    }
                }
                m
            }
        }
    }
}

/// Quads of a (rings x seg) vertex grid, outward-facing for the parameterisations above.
fn grid_indices(m: &mut Mesh, rings: usize, seg: usize) {
    let stride = (seg + 1) as u32;
    for i in 0..rings as u32 {
        for j in 0..seg as u32 {
            let a = i * stride + j;
            let b = a + stride;
            m.indices.push([a, b, a + 1]);
            m.indices.push([a + 1, b, b + 1]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distances_and_push_out() {
        let cap = Shape::Capsule {
            a: DVec3::ZERO,
            b: DVec3::X,
            r: 0.1,
        };
        assert!((cap.sdf(DVec3::new(0.5, 0.3, 0.0)) - 0.2).abs() < 1e-12);
        let (p, n) = cap.push_out(DVec3::new(0.5, 0.05, 0.0), 0.01).unwrap();
        assert!((p.y - 0.11).abs() < 1e-12 && (n - DVec3::Y).length() < 1e-12);
        let ell = Shape::Ellipsoid {
            c: DVec3::ZERO,
            rot: DMat3::IDENTITY,
            radii: DVec3::new(0.2, 0.1, 0.3),
        };
        assert!(ell.sdf(DVec3::new(0.0, 0.0, 0.5)) > 0.0);
        let (p, _) = ell.push_out(DVec3::new(0.0, 0.0, 0.1), 0.0).unwrap();
        assert!((p.z - 0.3).abs() < 1e-9);
        let bx = Shape::Box {
            c: DVec3::ZERO,
            rot: DMat3::IDENTITY,
            half: DVec3::new(1.0, 1.0, 0.1),
        };
        assert!((surface_height(&[bx], 0.3, 0.2, 1.0, -1.0).unwrap() - 0.1).abs() < 1e-3);
        assert!(surface_height(&[bx], 3.0, 0.0, 1.0, -1.0).is_none());
    }

    #[test]
    fn meshes_face_outwards() {
        for shape in [
            Shape::Capsule {
                a: DVec3::ZERO,
                b: DVec3::new(0.0, 0.3, 0.1),
                r: 0.05,
            },
            Shape::Ellipsoid {
                c: DVec3::ONE,
                rot: DMat3::from_rotation_z(0.3),
                radii: DVec3::new(0.1, 0.2, 0.3),
            },
            Shape::Box {
                c: DVec3::ZERO,
                rot: DMat3::IDENTITY,
                half: DVec3::new(0.1, 0.2, 0.3),
            },
        ] {
            let m = Mesh::of(&shape, 12);
            let centroid = m.positions.iter().copied().sum::<DVec3>() / m.positions.len() as f64;
            let mut outward = 0;
            let mut total = 0;
            for t in &m.indices {
                let [a, b, c] = t.map(|i| m.positions[i as usize]);
                let n = (b - a).cross(c - a);
                if n.length() < 1e-12 {
                    continue;
                }
                total += 1;
                if n.dot((a + b + c) / 3.0 - centroid) > 0.0 {
                    outward += 1;
                }
            }
            assert_eq!(outward, total, "{shape:?}");
        }
    }
}
