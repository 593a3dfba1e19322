//! A small software renderer: z-buffered triangle rasterisation with perspective-correct
//! normals, Lambert shading from a ceiling light, near-plane clipping, supersampling for
//! anti-aliasing, and a per-pixel object id (used to measure occlusion).

use glam::{DVec3, Vec3};

use crate::math::tan;
use crate::shapes::Mesh;

/// Surface appearance of a mesh.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Material {
    /// sRGB albedo in [0, 1].
    pub color: [f32; 3],
    /// Object id written to the id buffer (0 = background).
    pub id: u8,
    /// Render both faces (open surfaces such as the towel).
    pub double_sided: bool,
}

/// A pinhole camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub eye: DVec3,
    pub forward: DVec3,
    pub right: DVec3,
    pub up: DVec3,
    /// Vertical field of view (rad).
    pub fov_y: f64,
}

impl Camera {
    pub fn look_at(eye: DVec3, target: DVec3, world_up: DVec3, fov_y: f64) -> Self {
        let forward = (target - eye).normalize();
        let right = forward.cross(world_up).normalize();
        let up = right.cross(forward);
        Self {
            eye,
            forward,
            right,
            up,
            fov_y,
        }
    }

    /// Camera-space coordinates (right, up, forward) of a world point.
    fn camera_coords(&self, p: DVec3) -> Vec3 {
        let d = p - self.eye;
        Vec3::new(
            d.dot(self.right) as f32,
            d.dot(self.up) as f32,
            d.dot(self.forward) as f32,
        )
    }
}

/// A rendered image with its object ids.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    pub size: usize,
    /// `[size, size, 3]` sRGB bytes.
    pub rgb: Vec<u8>,
    /// `[size, size]` object id at each pixel's centre sample.
    pub ids: Vec<u8>,
}

impl Frame {
    /// Pixels showing object `id`.
    pub fn count(&self, id: u8) -> usize {
        self.ids.iter().filter(|&&i| i == id).count()
    }
}

const NEAR: f32 = 0.02;
const LIGHT: Vec3 = Vec3::new(0.25, 0.35, 0.9);
const AMBIENT: f32 = 0.42;
const DIFFUSE: f32 = 0.5;
const HEADLIGHT: f32 = 0.12;

struct Target {
    w: usize,
    color: Vec<[f32; 3]>,
    depth: Vec<f32>,
    ids: Vec<u8>,
}

/// Renders `items` from `camera` at `size` x `size`, computed at `supersample` times the
/// resolution in each direction and box-filtered down.
pub fn render(
    items: &[(&Mesh, Material)],
    camera: &Camera,
    size: usize,
    supersample: usize,
    background: [f32; 3],
) -> Frame {
    let w = size * supersample;
    let mut target = Target {
        w,
        color: vec![background; w * w],
        depth: vec![f32::INFINITY; w * w],
        ids: vec![0; w * w],
    };
    let focal = (0.5 * w as f64 / tan(0.5 * camera.fov_y)) as f32;
    let light = LIGHT.normalize();
    let toward_camera = -Vec3::new(
        camera.forward.x as f32,
        camera.forward.y as f32,
        camera.forward.z as f32,
    );
    for (mesh, material) in items {
        let cam: Vec<Vec3> = mesh
            .positions
            .iter()
            .map(|&p| camera.camera_coords(p))
            .collect();
        let normals: Vec<Vec3> = mesh.normals.iter().map(|n| n.as_vec3()).collect();
        for tri in &mesh.indices {
            let [i0, i1, i2] = tri.map(|i| i as usize);
            let (p0, p1, p2) = (cam[i0], cam[i1], cam[i2]);
            let face = (p1 - p0).cross(p2 - p0);
            let facing_away = face.dot(p0) >= 0.0;
            if facing_away && !material.double_sided {
                continue;
            }
            let flip = if facing_away { -1.0 } else { 1.0 };
            let verts = [
                (p0, normals[i0] * flip),
                (p1, normals[i1] * flip),
                (p2, normals[i2] * flip),
            ];
            for clipped in clip_near(verts) {
                raster(&mut target, &clipped, focal, material, light, toward_camera);
            }
        }
    }
    downsample(&target, size, supersample)
}

type Vertex = (Vec3, Vec3);

/// Clips a triangle against the near plane: 0, 1 or 2 triangles.
fn clip_near(v: [Vertex; 3]) -> Vec<[Vertex; 3]> {
    let inside: Vec<bool> = v.iter().map(|(p, _)| p.z >= NEAR).collect();
    let count = inside.iter().filter(|&&b| b).count();
    if count == 3 {
        return vec![v];
    }
    if count == 0 {
        return Vec::new();
    }
    let lerp = |a: &Vertex, b: &Vertex| -> Vertex {
        let t = (NEAR - a.0.z) / (b.0.z - a.0.z);
        (a.0 + (b.0 - a.0) * t, a.1 + (b.1 - a.1) * t)
    };
    let mut poly: Vec<Vertex> = Vec::with_capacity(4);
    for i in 0..3 {
        let (a, b) = (&v[i], &v[(i + 1) % 3]);
        if inside[i] {
            poly.push(*a);
        }
        if inside[i] != inside[(i + 1) % 3] {
            poly.push(lerp(a, b));
        }
    }
    (1..poly.len() - 1)
        .map(|i| [poly[0], poly[i], poly[i + 1]])
        .collect()
}

fn raster(
    t: &mut Target,
    v: &[Vertex; 3],
    focal: f32,
    m: &Material,
    light: Vec3,
    toward_camera: Vec3,
) {
    let half = t.w as f32 * 0.5;
    let screen = v.map(|(p, _)| {
        (
            half + focal * p.x / p.z,
            half - focal * p.y / p.z,
            1.0 / p.z,
        )
    });
    let [(x0, y0, iz0), (x1, y1, iz1), (x2, y2, iz2)] = screen;
    let area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0);
    if area.abs() < 1e-12 {
        return;
    }
    let (min_x, max_x) = (x0.min(x1).min(x2), x0.max(x1).max(x2));
    let (min_y, max_y) = (y0.min(y1).min(y2), y0.max(y1).max(y2));
    let wf = t.w as f32;
    if max_x < 0.0 || max_y < 0.0 || min_x >= wf || min_y >= wf {
        return;
    }
    let (xs, xe) = (
        (min_x.floor().max(0.0)) as usize,
        (max_x.ceil().min(wf - 1.0)) as usize,
    );
    let (ys, ye) = (
        (min_y.floor().max(0.0)) as usize,
        (max_y.ceil().min(wf - 1.0)) as usize,
    );
    let inv_area = 1.0 / area;
    // Attributes divided by z, for perspective-correct interpolation.
    let n_over_z = [v[0].1 * iz0, v[1].1 * iz1, v[2].1 * iz2];
    let albedo = Vec3::from(m.color);
    for py in ys..=ye {
        let sy = py as f32 + 0.5;
        for px in xs..=xe {
            let sx = px as f32 + 0.5;
            let b0 = ((x1 - sx) * (y2 - sy) - (x2 - sx) * (y1 - sy)) * inv_area;
            let b1 = ((x2 - sx) * (y0 - sy) - (x0 - sx) * (y2 - sy)) * inv_area;
            let b2 = 1.0 - b0 - b1;
            if b0 < 0.0 || b1 < 0.0 || b2 < 0.0 {
                continue;
            }
            let inv_z = b0 * iz0 + b1 * iz1 + b2 * iz2;
            let z = 1.0 / inv_z;
            let idx = py * t.w + px;
            if z >= t.depth[idx] {
                continue;
            }
            t.depth[idx] = z;
            let n =
                ((n_over_z[0] * b0 + n_over_z[1] * b1 + n_over_z[2] * b2) * z).normalize_or_zero();
            let shade = AMBIENT
                + DIFFUSE * n.dot(light).max(0.0)
                + HEADLIGHT * n.dot(toward_camera).max(0.0);
            let c = albedo * shade;
            t.color[idx] = [c.x.min(1.0), c.y.min(1.0), c.z.min(1.0)];
            t.ids[idx] = m.id;
        }
    }
}

fn downsample(t: &Target, size: usize, ss: usize) -> Frame {
    let mut rgb = vec![0u8; size * size * 3];
    let mut ids = vec![0u8; size * size];
    let norm = 1.0 / (ss * ss) as f32;
    for y in 0..size {
        for x in 0..size {
            let mut acc = [0f32; 3];
            for sy in 0..ss {
                for sx in 0..ss {
                    let c = t.color[(y * ss + sy) * t.w + x * ss + sx];
                    for k in 0..3 {
                        acc[k] += c[k];
                    }
                }
            }
            for k in 0..3 {
                rgb[(y * size + x) * 3 + k] =
                    (acc[k] * norm * 255.0).round().clamp(0.0, 255.0) as u8;
            }
            ids[y * size + x] = t.ids[(y * ss + ss / 2) * t.w + x * ss + ss / 2];
        }
    }
    Frame { size, rgb, ids }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shapes::Shape;
    use glam::DMat3;

    fn sphere_at(c: DVec3, r: f64) -> Mesh {
        Mesh::of(
            &Shape::Ellipsoid {
                c,
                rot: DMat3::IDENTITY,
                radii: DVec3::splat(r),
            },
            24,
        )
    }

    #[test]
    fn nearer_objects_hide_farther_ones_and_edges_are_antialiased() {
        let cam = Camera::look_at(DVec3::ZERO, DVec3::X, DVec3::Z, 0.8);
        let near = sphere_at(DVec3::new(2.0, 0.0, 0.0), 0.3);
        let far = sphere_at(DVec3::new(4.0, 0.0, 0.0), 1.0);
        let red = Material {
            color: [1.0, 0.0, 0.0],
            id: 1,
            double_sided: false,
        };
        let blue = Material {
            color: [0.0, 0.0, 1.0],
            id: 2,
            double_sided: false,
        };
        // Draw order must not matter.
        let a = render(&[(&near, red), (&far, blue)], &cam, 32, 4, [0.0; 3]);
        let b = render(&[(&far, blue), (&near, red)], &cam, 32, 4, [0.0; 3]);
        assert_eq!(a, b);
        let centre = 16 * 32 + 16;
        assert_eq!(a.ids[centre], 1);
        assert!(a.count(2) > 0 && a.count(1) > 0);
        // Anti-aliasing: some pixels mix red and blue.
        let mixed = (0..32 * 32)
            .filter(|&i| a.rgb[i * 3] > 20 && a.rgb[i * 3 + 2] > 20)
            .count();
        assert!(mixed > 0);
    }

    #[test]
    fn geometry_behind_the_camera_is_clipped() {
        let cam = Camera::look_at(DVec3::ZERO, DVec3::X, DVec3::Z, 1.0);
        let behind = sphere_at(DVec3::new(-1.0, 0.0, 0.0), 0.5);
        let around = sphere_at(DVec3::ZERO, 0.5); // camera inside: only the far half is seen
        let m = Material {
            color: [1.0; 3],
            id: 3,
            double_sided: true,
        };
        assert_eq!(render(&[(&behind, m)], &cam, 16, 2, [0.0; 3]).count(3), 0);
        assert!(render(&[(&around, m)], &cam, 16, 2, [0.0; 3]).count(3) > 200);
    }
}
