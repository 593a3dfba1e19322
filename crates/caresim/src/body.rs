//! The care recipient: a supine mannequin of the paper's dimensions (height 1800 mm,
//! shoulder width 470 mm, leg length 885 mm, arm length 750 mm, mass 8 kg) made of
//! capsules and ellipsoids, lying on the bed with its head to the robot's left.
//!
//! Body coordinates: x lateral (towards the far side of the bed), y along the body
//! (towards the head), z up from the mattress; the origin is the hip joint centre line on
//! the mattress. Lifting rotates everything above the hips about the hips' lateral axis.

use glam::{DMat3, DVec3};

use crate::shapes::Shape;

pub const HEIGHT: f64 = 1.80;
pub const SHOULDER_WIDTH: f64 = 0.47;
pub const LEG_LENGTH: f64 = 0.885;
pub const ARM_LENGTH: f64 = 0.75;
pub const MASS: f64 = 8.0;
/// Share of the mass above the hips and the distance of its centre of mass from them.
pub const UPPER_MASS: f64 = 0.55 * MASS;
pub const UPPER_COM: f64 = 0.30;
/// Height of the pivot (hip axis) above the mattress.
const PIVOT_Z: f64 = 0.10;
/// Pillow under the head.
const PILLOW: f64 = 0.045;

/// What a part is made of, for colour.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Skin {
    Skin,
    Hair,
    Gown,
    Trousers,
}

/// One rigid part.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Part {
    pub shape: Shape,
    pub skin: Skin,
    /// Above the hips: rotates with the upper body.
    pub upper: bool,
}

/// A trial's variations of the lying posture.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Posture {
    /// Shift of the hips on the bed (world x, world y), m.
    pub offset: [f64; 2],
    /// Rotation of the body about the vertical, rad.
    pub yaw: f64,
    /// Rotation of the head about the body axis, rad.
    pub head_yaw: f64,
    /// Outward shift of the hands (left, right), m.
    pub arm_spread: [f64; 2],
    /// Outward shift of the feet, m.
    pub leg_spread: f64,
}

/// The mannequin on a bed.
#[derive(Clone, Debug, PartialEq)]
pub struct Mannequin {
    pub posture: Posture,
    /// World position of the body origin (hips on the mattress).
    pub origin: DVec3,
    /// World orientation of the body axes.
    pub frame: DMat3,
    parts: Vec<Part>,
}

/// Points the task scripts aim at, in world coordinates.
#[derive(Clone, Copy, Debug)]
pub struct Landmarks {
    /// On the mattress under the neck.
    pub under_neck: DVec3,
    /// On the mattress under the upper back.
    pub under_back: DVec3,
    /// Top of the near (robot-side) knee.
    pub near_knee: DVec3,
    /// Middle of the belly, on the body's surface line.
    pub belly: DVec3,
    /// The hips' lateral axis (pivot of the lift) and its direction.
    pub pivot: DVec3,
    pub pivot_axis: DVec3,
    /// Unit vector along the body towards the head.
    pub along: DVec3,
}

impl Mannequin {
    /// A mannequin whose hips sit at `hips` (world x, y) on a mattress at height `bed_top`.
    pub fn new(hips: [f64; 2], bed_top: f64, posture: Posture) -> Self {
        let origin = DVec3::new(
            hips[0] + posture.offset[0],
            hips[1] + posture.offset[1],
            bed_top,
        );
        let frame = DMat3::from_rotation_z(posture.yaw);
        Self {
            posture,
            origin,
            frame,
            parts: local_parts(&posture),
        }
    }

    fn to_world(&self, local: DVec3) -> DVec3 {
        self.origin + self.frame * local
    }

    /// Local-frame transform of the upper body lifted by `lift` rad.
    fn lifted(lift: f64, p: DVec3) -> DVec3 {
        let pivot = DVec3::new(0.0, 0.0, PIVOT_Z);
        pivot + DMat3::from_rotation_x(lift) * (p - pivot)
    }

    /// The parts in world coordinates with the upper body lifted by `lift` rad.
    pub fn parts(&self, lift: f64) -> Vec<Part> {
        self.parts
            .iter()
            .map(|p| {
                let place =
                    |v: DVec3| self.to_world(if p.upper { Self::lifted(lift, v) } else { v });
                let turn = |r: DMat3| {
                    if p.upper {
                        self.frame * DMat3::from_rotation_x(lift) * r
                    } else {
                        self.frame * r
                    }
                };
                let shape = match p.shape {
                    Shape::Capsule { a, b, r } => Shape::Capsule {
                        a: place(a),
                        b: place(b),
                        r,
                    },
                    Shape::Ellipsoid { c, rot, radii } => Shape::Ellipsoid {
                        c: place(c),
                        rot: turn(rot),
                        radii,
                    },
                    Shape::Box { c, rot, half } => Shape::Box {
                        c: place(c),
                        rot: turn(rot),
                        half,
                    },
                };
                Part { shape, ..*p }
            })
            .collect()
    }

    pub fn shapes(&self, lift: f64) -> Vec<Shape> {
        self.parts(lift).into_iter().map(|p| p.shape).collect()
    }

    /// The world point of a body-frame point on the upper body lifted by `lift`.
    pub fn upper_point(&self, local: DVec3, lift: f64) -> DVec3 {
        self.to_world(Self::lifted(lift, local))
    }

    pub fn landmarks(&self) -> Landmarks {
        Landmarks {
            under_neck: self.to_world(DVec3::new(0.0, 0.57, 0.0)),
            under_back: self.to_world(DVec3::new(0.0, 0.34, 0.0)),
            near_knee: self.to_world(DVec3::new(
                -0.10 - 0.5 * self.posture.leg_spread,
                -0.45,
                0.155,
            )),
            belly: self.to_world(DVec3::new(0.0, 0.16, 0.0)),
            pivot: self.to_world(DVec3::new(0.0, 0.0, PIVOT_Z)),
            pivot_axis: self.frame * DVec3::X,
            along: self.frame * DVec3::Y,
        }
    }

    /// A body-frame point's local coordinates (inverse of the placement).
    pub fn to_local(&self, world: DVec3) -> DVec3 {
        self.frame.transpose() * (world - self.origin)
    }
}

/// The parts in body coordinates (y from the hips to the head, z up from the mattress).
fn local_parts(posture: &Posture) -> Vec<Part> {
    let ell = |c: DVec3, radii: DVec3| Shape::Ellipsoid {
        c,
        rot: DMat3::IDENTITY,
        radii,
    };
    let cap = |a: DVec3, b: DVec3, r: f64| Shape::Capsule { a, b, r };
    let v = DVec3::new;
    let head_rot = DMat3::from_rotation_y(posture.head_yaw);
    let head_c = v(0.0, 0.785, 0.10 + PILLOW);
    let on_head = |offset: DVec3| head_c + head_rot * offset;
    let mut parts = vec![
        // Trunk.
        (
            ell(v(0.0, 0.02, 0.10), v(0.17, 0.13, 0.10)),
            Skin::Trousers,
            false,
        ),
        (
            ell(v(0.0, 0.20, 0.10), v(0.155, 0.16, 0.095)),
            Skin::Gown,
            true,
        ),
        (
            ell(v(0.0, 0.37, 0.11), v(0.175, 0.16, 0.11)),
            Skin::Gown,
            true,
        ),
        (
            cap(v(-0.175, 0.47, 0.09), v(0.175, 0.47, 0.09), 0.06),
            Skin::Gown,
            true,
        ),
        (
            cap(v(0.0, 0.50, 0.08), v(0.0, 0.65, 0.09 + 0.5 * PILLOW), 0.048),
            Skin::Skin,
            true,
        ),
        // Head on the pillow, turned by head_yaw: skull, hair, nose.
        (
            Shape::Ellipsoid {
                c: head_c,
                rot: head_rot,
                radii: v(0.078, 0.12, 0.095),
            },
            Skin::Skin,
            true,
        ),
        (
            Shape::Ellipsoid {
                c: on_head(v(0.0, 0.018, -0.012)),
                rot: head_rot,
                radii: v(0.083, 0.112, 0.088),
            },
            Skin::Hair,
            true,
        ),
        (
            Shape::Ellipsoid {
                c: on_head(v(0.0, -0.005, 0.094)),
                rot: head_rot,
                radii: v(0.014, 0.024, 0.018),
            },
            Skin::Skin,
            true,
        ),
    ];
    // Arms (upper arm 0.30, forearm 0.27, hand 0.16 with radii: ~0.75) and legs.
    for (side, spread) in [(-1.0, posture.arm_spread[1]), (1.0, posture.arm_spread[0])] {
        let shoulder = v(side * 0.2, 0.46, 0.08);
        let elbow = v(side * (0.245 + 0.4 * spread), 0.165, 0.07);
        let wrist = v(side * (0.26 + spread), -0.10, 0.065);
        parts.push((cap(shoulder, elbow, 0.043), Skin::Gown, true));
        parts.push((cap(elbow, wrist, 0.035), Skin::Skin, true));
        parts.push((
            ell(wrist + v(0.0, -0.075, -0.01), v(0.032, 0.075, 0.022)),
            Skin::Skin,
            true,
        ));
    }
    for side in [-1.0, 1.0] {
        let hip = v(side * 0.09, -0.02, 0.085);
        let knee = v(side * (0.10 + 0.5 * posture.leg_spread), -0.45, 0.075);
        let ankle = v(side * (0.10 + posture.leg_spread), -0.84, 0.055);
        parts.push((cap(hip, knee, 0.078), Skin::Trousers, false));
        parts.push((cap(knee, ankle, 0.052), Skin::Trousers, false));
        parts.push((
            cap(ankle, ankle + v(0.0, -0.005, 0.13), 0.04),
            Skin::Skin,
            false,
        ));
    }
    parts
        .into_iter()
        .map(|(shape, skin, upper)| Part { shape, skin, upper })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dimensions_are_the_papers() {
        let m = Mannequin::new([0.0, 0.0], 0.0, Posture::default());
        let shapes = m.shapes(0.0);
        // Extent along the body: sample the union's occupancy on the body axis plane.
        let occupied = |y: f64, x: f64| {
            (0..60).any(|k| {
                crate::shapes::union_sdf(&shapes, DVec3::new(x, y, k as f64 * 0.005)) < 0.0
            })
        };
        let along: Vec<f64> = (-1000..1000)
            .map(|i| i as f64 * 0.001)
            .filter(|&y| occupied(y, 0.0) || occupied(y, 0.1) || occupied(y, -0.1))
            .collect();
        let height = along.last().unwrap() - along.first().unwrap();
        assert!((height - HEIGHT).abs() < 0.03, "height {height}");
        let across: Vec<f64> = (-500..500)
            .map(|i| i as f64 * 0.001)
            .filter(|&x| occupied(0.47, x))
            .collect();
        let width = across.last().unwrap() - across.first().unwrap();
        assert!(
            (width - SHOULDER_WIDTH).abs() < 0.03,
            "shoulder width {width}"
        );
        // Legs: hip joint (y = -0.02) to the sole.
        let leg = -0.02 - along.first().unwrap();
        assert!((leg - LEG_LENGTH).abs() < 0.03, "leg length {leg}");
    }

    #[test]
    fn lifting_raises_the_head_and_keeps_the_legs() {
        let m = Mannequin::new([0.5, 0.0], 0.6, Posture::default());
        let head = |lift: f64| m.parts(lift)[5].shape;
        let Shape::Ellipsoid { c: c0, .. } = head(0.0) else {
            panic!()
        };
        let Shape::Ellipsoid { c: c1, .. } = head(0.9) else {
            panic!()
        };
        assert!(c1.z > c0.z + 0.4 && c1.y < c0.y);
        assert_eq!(m.parts(0.0).last(), m.parts(0.9).last());
    }
}
