//! The robot, the bed and the room: geometry, colours and the binocular head cameras.
//!
//! World: x forward from the robot towards the bed, y to the robot's left, z up; metres.

use glam::{DAffine3, DMat3, DVec3};

use crate::arm::{Arm, DOF};
use crate::body::{Mannequin, Skin};
use crate::render::{Camera, Material};
use crate::shapes::{Mesh, Shape};

pub const ID_BODY: u8 = 1;
pub const ID_ROBOT: u8 = 2;
pub const ID_TOWEL: u8 = 3;
pub const ID_BED: u8 = 4;
pub const ID_ROOM: u8 = 5;

pub const BACKGROUND: [f32; 3] = [0.80, 0.80, 0.77];

fn rgb(r: u8, g: u8, b: u8) -> [f32; 3] {
    [r as f32 / 255.0, g as f32 / 255.0, b as f32 / 255.0]
}

fn material(color: [f32; 3], id: u8) -> Material {
    Material {
        color,
        id,
        double_sided: false,
    }
}

pub fn skin_material(skin: Skin) -> Material {
    let color = match skin {
        Skin::Skin => rgb(226, 186, 156),
        Skin::Hair => rgb(62, 46, 36),
        Skin::Gown => rgb(118, 172, 152),
        Skin::Trousers => rgb(84, 104, 156),
    };
    material(color, ID_BODY)
}

pub fn towel_material() -> Material {
    Material {
        color: rgb(242, 146, 38),
        id: ID_TOWEL,
        double_sided: true,
    }
}

/// Bed geometry: the mattress spans x in [BED_NEAR, BED_FAR], y in [-BED_HALF_LENGTH, +].
pub const BED_NEAR: f64 = 0.30;
pub const BED_FAR: f64 = 1.20;
pub const BED_HALF_LENGTH: f64 = 1.05;
const MATTRESS: f64 = 0.14;
/// Where the hips lie on the bed (world x, y) before the trial's posture offset.
pub const HIPS: [f64; 2] = [0.64, -0.06];

/// Static meshes of the bed (mattress top at `bed_top`), a pillow under the head, and the room.
pub fn room_meshes(bed_top: f64, head: DVec3) -> Vec<(Mesh, Material)> {
    let bx = |c: DVec3, half: DVec3| Shape::Box {
        c,
        rot: DMat3::IDENTITY,
        half,
    };
    let mid_x = 0.5 * (BED_NEAR + BED_FAR);
    let half_w = 0.5 * (BED_FAR - BED_NEAR);
    let mut out = vec![
        (
            Mesh::of(
                &bx(
                    DVec3::new(mid_x, 0.0, bed_top - MATTRESS / 2.0),
                    DVec3::new(half_w, BED_HALF_LENGTH, MATTRESS / 2.0),
                ),
                4,
            ),
            material(rgb(176, 206, 228), ID_BED),
        ),
        (
            Mesh::of(
                &bx(
                    DVec3::new(mid_x, 0.0, bed_top - MATTRESS - 0.04),
                    DVec3::new(half_w + 0.02, BED_HALF_LENGTH + 0.02, 0.04),
                ),
                4,
            ),
            material(rgb(92, 94, 104), ID_BED),
        ),
        (
            Mesh::of(
                &bx(
                    DVec3::new(mid_x, 0.0, (bed_top - MATTRESS - 0.08) / 2.0),
                    DVec3::new(
                        half_w - 0.05,
                        BED_HALF_LENGTH - 0.1,
                        (bed_top - MATTRESS - 0.08) / 2.0,
                    ),
                ),
                4,
            ),
            material(rgb(70, 72, 80), ID_BED),
        ),
        (
            Mesh::of(
                &bx(DVec3::new(1.0, 0.0, -0.05), DVec3::new(4.0, 8.0, 0.05)),
                4,
            ),
            material(rgb(152, 140, 122), ID_ROOM),
        ),
        (
            Mesh::of(
                &bx(DVec3::new(2.6, 0.0, 1.2), DVec3::new(0.05, 8.0, 1.3)),
                4,
            ),
            material(rgb(214, 212, 200), ID_ROOM),
        ),
        (
            Mesh::of(
                &bx(DVec3::new(0.0, 2.4, 1.2), DVec3::new(4.0, 0.05, 1.3)),
                4,
            ),
            material(rgb(204, 206, 196), ID_ROOM),
        ),
    ];
    let pillow = Shape::Ellipsoid {
        c: DVec3::new(head.x, head.y + 0.02, bed_top + 0.02),
        rot: DMat3::IDENTITY,
        radii: DVec3::new(0.26, 0.17, 0.045),
    };
    out.push((Mesh::of(&pillow, 20), material(rgb(246, 246, 240), ID_BED)));
    out
}

/// The mannequin's meshes with the upper body lifted by `lift`.
pub fn body_meshes(body: &Mannequin, lift: f64) -> Vec<(Mesh, Material)> {
    body.parts(lift)
        .into_iter()
        .map(|p| (Mesh::of(&p.shape, 18), skin_material(p.skin)))
        .collect()
}

/// The dual-arm humanoid.
#[derive(Clone, Debug)]
pub struct Robot {
    /// Left arm, right arm.
    pub arms: [Arm; 2],
    /// Comfortable postures the inverse kinematics is pulled towards.
    pub rest: [[f64; DOF]; 2],
    /// Left camera, right camera.
    pub cameras: [Camera; 2],
}

pub const SHOULDER_HEIGHT: f64 = 1.17;
pub const SHOULDER_HALF_WIDTH: f64 = 0.21;
/// Stereo baseline of the head cameras (m).
pub const BASELINE: f64 = 0.064;

/// How the arms are mounted: the base position (left arm; the right is mirrored) and the
/// direction of joint 1's axis, plus the rest posture.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Mount {
    pub base: DVec3,
    /// Joint-1 axis of the left arm (mirrored in y for the right).
    pub axis: DVec3,
    pub rest: [f64; DOF],
}

impl Mount {
    fn base_frame(&self, side: f64) -> DAffine3 {
        let mirror = DVec3::new(1.0, side, 1.0);
        let z = (self.axis * mirror).normalize();
        // Base x: the world forward direction made perpendicular to the axis (or down).
        let pick = if z.dot(DVec3::X).abs() > 0.9 {
            DVec3::NEG_Z
        } else {
            DVec3::X
        };
        let x = (pick - z * pick.dot(z)).normalize();
        let y = z.cross(x);
        DAffine3::from_mat3_translation(DMat3::from_cols(x, y, z), self.base * mirror)
    }
}

impl Default for Mount {
    fn default() -> Self {
        Self {
            base: DVec3::new(0.0, SHOULDER_HALF_WIDTH, SHOULDER_HEIGHT),
            // Arms hang from the shoulders. The rest posture was chosen by a random search
            // (examples/mount_search.rs): exact IK on both tasks with the elbows lowest.
            axis: DVec3::NEG_Z,
            rest: [0.241, -0.249, 0.345, -2.399, -0.521, 1.440, 0.785],
        }
    }
}

impl Default for Robot {
    fn default() -> Self {
        Self::with_mount(Mount::default())
    }
}

impl Robot {
    pub fn with_mount(mount: Mount) -> Self {
        let arms = [
            Arm {
                base: mount.base_frame(1.0),
            },
            Arm {
                base: mount.base_frame(-1.0),
            },
        ];
        // Mirror image across the robot's sagittal plane: joints 1, 3, 5 and 7 turn the other way.
        let rest_left = mount.rest;
        let r = mount.rest;
        let rest_right = [-r[0], r[1], -r[2], r[3], -r[4], r[5], -r[6]];
        // Parallel binocular pair in the head, looking down at the bed.
        let mid = DVec3::new(0.07, 0.0, 1.46);
        let look = Camera::look_at(
            mid,
            DVec3::new(0.68, 0.26, 0.64),
            DVec3::Z,
            72f64.to_radians(),
        );
        let eye = |side: f64| Camera {
            eye: mid - look.right * (side * BASELINE / 2.0),
            ..look
        };
        Self {
            arms,
            rest: [rest_left, rest_right],
            cameras: [eye(1.0), eye(-1.0)],
        }
    }

    /// Meshes of the torso, shoulders and both arms at configuration `q`.
    pub fn meshes(&self, q: &[[f64; DOF]; 2]) -> Vec<(Mesh, Material)> {
        let white = material(rgb(236, 236, 240), ID_ROBOT);
        let dark = material(rgb(58, 60, 70), ID_ROBOT);
        let mut shell = Mesh::default();
        let mut joints = Mesh::default();
        shell.extend(&Mesh::of(
            &Shape::Box {
                c: DVec3::new(-0.13, 0.0, 0.86),
                rot: DMat3::IDENTITY,
                half: DVec3::new(0.12, 0.19, 0.32),
            },
            4,
        ));
        shell.extend(&Mesh::of(
            &Shape::Capsule {
                a: DVec3::new(-0.02, -SHOULDER_HALF_WIDTH, SHOULDER_HEIGHT + 0.02),
                b: DVec3::new(-0.02, SHOULDER_HALF_WIDTH, SHOULDER_HEIGHT + 0.02),
                r: 0.065,
            },
            14,
        ));
        for (arm, q) in self.arms.iter().zip(q) {
            let k = arm.fk(q);
            let mut points = vec![arm.base.translation];
            points.extend(k.joints.iter().map(|f| f.translation));
            points.push(k.flange.translation);
            points.dedup_by(|a, b| (*a - *b).length() < 1e-6);
            for (i, pair) in points.windows(2).enumerate() {
                let r = if i < 4 { 0.058 } else { 0.046 };
                shell.extend(&Mesh::of(
                    &Shape::Capsule {
                        a: pair[0],
                        b: pair[1],
                        r,
                    },
                    14,
                ));
            }
            for p in &points[1..] {
                joints.extend(&Mesh::of(
                    &Shape::Ellipsoid {
                        c: *p,
                        rot: DMat3::IDENTITY,
                        radii: DVec3::splat(0.062),
                    },
                    12,
                ));
            }
            joints.extend(&Mesh::of(&hand_shape(&k.tcp), 4));
        }
        vec![(shell, white), (joints, dark)]
    }
}

/// The hand: a paddle around the palm centre, fingers along the tcp z axis.
pub fn hand_shape(tcp: &DAffine3) -> Shape {
    Shape::Box {
        c: tcp.transform_point3(DVec3::new(0.0, 0.0, -0.01)),
        rot: tcp.matrix3,
        half: DVec3::new(0.045, 0.016, 0.07),
    }
}
