//! A 7-DOF arm with the Franka Emika Panda's published kinematics (modified DH, Craig's
//! convention), joint limits and link masses: forward kinematics, the geometric Jacobian,
//! damped-least-squares inverse kinematics, and static joint torques.

use glam::{DAffine3, DMat3, DVec3};

pub const DOF: usize = 7;

/// Modified DH rows (a_{i-1}, d_i, alpha_{i-1}) of the Panda, then the flange.
const DH: [(f64, f64, f64); DOF] = [
    (0.0, 0.333, 0.0),
    (0.0, 0.0, -std::f64::consts::FRAC_PI_2),
    (0.0, 0.316, std::f64::consts::FRAC_PI_2),
    (0.0825, 0.0, std::f64::consts::FRAC_PI_2),
    (-0.0825, 0.384, -std::f64::consts::FRAC_PI_2),
    (0.0, 0.0, std::f64::consts::FRAC_PI_2),
    (0.088, 0.0, std::f64::consts::FRAC_PI_2),
];
const FLANGE_D: f64 = 0.107;
/// Tool centre point (the palm) beyond the flange, along the flange's z.
pub const TCP_OFFSET: f64 = 0.09;

pub const Q_MIN: [f64; DOF] = [
    -2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973,
];
pub const Q_MAX: [f64; DOF] = [2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973];
/// Rated joint torques (N m).
pub const TAU_MAX: [f64; DOF] = [87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0];
/// Link masses (kg) from the Panda's published dynamic identification; the last entry adds
/// the hand. Each link's centre of mass is taken at the midpoint of its two joint origins.
const LINK_MASS: [f64; DOF] = [4.97, 0.65, 3.23, 3.59, 1.23, 1.67, 0.74 + 0.73];
pub const GRAVITY: f64 = 9.81;

/// One arm: its base pose in the world.
#[derive(Clone, Copy, Debug)]
pub struct Arm {
    pub base: DAffine3,
}

/// Forward kinematics of one configuration.
#[derive(Clone, Debug)]
pub struct Kinematics {
    /// World frame of each joint (its z axis is the joint axis).
    pub joints: [DAffine3; DOF],
    pub flange: DAffine3,
    /// The hand's palm centre frame: z along the fingers.
    pub tcp: DAffine3,
}

fn mdh(a: f64, d: f64, alpha: f64, theta: f64) -> DAffine3 {
    DAffine3::from_rotation_x(alpha)
        * DAffine3::from_translation(DVec3::new(a, 0.0, 0.0))
        * DAffine3::from_rotation_z(theta)
        * DAffine3::from_translation(DVec3::new(0.0, 0.0, d))
}

/// Target of the inverse kinematics: a palm position and a finger direction.
#[derive(Clone, Copy, Debug)]
pub struct IkTarget {
    pub position: DVec3,
    /// Desired direction of the tcp z axis (unit).
    pub fingers: DVec3,
    /// Metres per radian of direction error (0 = position only).
    pub direction_weight: f64,
    /// The last joint (the wrist's roll about the fingers) set by the operator, as a turn
    /// from its rest angle; `None` leaves it to the solver. It moves neither the palm nor
    /// the finger direction, so setting it costs the other tasks nothing.
    pub wrist_twist: Option<f64>,
}

/// How the inverse kinematics ended.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IkReport {
    pub position_error: f64,
    pub direction_error: f64,
    pub iterations: usize,
}

impl Arm {
    pub fn fk(&self, q: &[f64; DOF]) -> Kinematics {
        let mut frame = self.base;
        let mut joints = [DAffine3::IDENTITY; DOF];
        for i in 0..DOF {
            let (a, d, alpha) = DH[i];
            frame *= mdh(a, d, alpha, q[i]);
            joints[i] = frame;
        }
        let flange = frame * DAffine3::from_translation(DVec3::new(0.0, 0.0, FLANGE_D));
        let tcp = flange * DAffine3::from_translation(DVec3::new(0.0, 0.0, TCP_OFFSET));
        Kinematics {
            joints,
            flange,
            tcp,
        }
    }

    /// Geometric Jacobian of the point `p` (linear rows) and the rotation (angular rows).
    fn jacobian(k: &Kinematics, p: DVec3) -> [[f64; DOF]; 6] {
        let mut j = [[0.0; DOF]; 6];
        for i in 0..DOF {
            let axis = k.joints[i].matrix3.z_axis;
            let lin = axis.cross(p - k.joints[i].translation);
            for r in 0..3 {
                j[r][i] = lin[r];
                j[3 + r][i] = axis[r];
            }
        }
        j
    }

    /// Task-priority inverse kinematics from the current `q`: the palm position is the
    /// primary task (damped least squares); the finger direction, a pull towards `rest`
    /// and away from joint limits act only in its null space, so they never cost position.
    pub fn solve_ik(&self, q: &mut [f64; DOF], target: &IkTarget, rest: &[f64; DOF]) -> IkReport {
        let mut report = IkReport {
            position_error: f64::INFINITY,
            direction_error: f64::INFINITY,
            iterations: 0,
        };
        let last = DOF - 1;
        if let Some(twist) = target.wrist_twist {
            q[last] = (rest[last] + twist).clamp(Q_MIN[last] + 1e-3, Q_MAX[last] - 1e-3);
        }
        for it in 0..300 {
            let k = self.fk(q);
            let p = k.tcp.translation;
            let z = k.tcp.matrix3.z_axis;
            let e_pos = target.position - p;
            let e_dir = z.cross(target.fingers);
            report = IkReport {
                position_error: e_pos.length(),
                direction_error: z.angle_between(target.fingers),
                iterations: it,
            };
            let direction_done = target.direction_weight == 0.0 || report.direction_error < 0.02;
            if report.position_error < 1e-4 && (direction_done || it > 60) {
                break;
            }
            let jac = Self::jacobian(&k, p);
            let jp = [jac[0], jac[1], jac[2]];
            // A = Jp Jp^T + lambda^2 I (3x3).
            let lambda2 = 1e-4;
            let mut a = [[0.0; 3]; 3];
            for r in 0..3 {
                for c in 0..3 {
                    a[r][c] = (0..DOF).map(|i| jp[r][i] * jp[c][i]).sum::<f64>()
                        + if r == c { lambda2 } else { 0.0 };
                }
            }
            let ainv = invert3(a);
            let apply = |v: [f64; 3]| -> [f64; 3] {
                std::array::from_fn(|r| (0..3).map(|c| ainv[r][c] * v[c]).sum())
            };
            let y = apply([e_pos.x, e_pos.y, e_pos.z]);
            let mut dq: [f64; DOF] = std::array::from_fn(|i| (0..3).map(|r| jp[r][i] * y[r]).sum());
            // Secondary objectives, projected into the position task's null space.
            let mut v = [0.0; DOF];
            for i in 0..DOF {
                let w = target.direction_weight;
                v[i] = w * (jac[3][i] * e_dir.x + jac[4][i] * e_dir.y + jac[5][i] * e_dir.z) * 4.0;
                let span = Q_MAX[i] - Q_MIN[i];
                let mid = 0.5 * (Q_MAX[i] + Q_MIN[i]);
                v[i] += 0.05 * (rest[i] - q[i]) - 0.1 * cube((q[i] - mid) / span) * 8.0;
            }
            let jv: [f64; 3] = std::array::from_fn(|r| (0..DOF).map(|i| jp[r][i] * v[i]).sum());
            let ajv = apply(jv);
            for i in 0..DOF {
                dq[i] += v[i] - (0..3).map(|r| jp[r][i] * ajv[r]).sum::<f64>();
            }
            let largest = dq.iter().fold(0.0f64, |m, d| m.max(d.abs()));
            let scale = if largest > 0.15 { 0.15 / largest } else { 1.0 };
            for i in 0..DOF {
                if i == last && target.wrist_twist.is_some() {
                    continue;
                }
                q[i] = (q[i] + scale * dq[i]).clamp(Q_MIN[i] + 1e-3, Q_MAX[i] - 1e-3);
            }
        }
        report
    }

    /// Static joint torques: holding the links against gravity, plus reacting to the force
    /// `hand_force` the environment applies at the palm's centre (tau = -J^T F).
    pub fn static_torques(&self, q: &[f64; DOF], hand_force: DVec3) -> [f64; DOF] {
        self.static_torques_at(q, hand_force, 0.0)
    }

    /// [`Arm::static_torques`] with the force acting `contact_offset` metres from the palm's
    /// centre along the hand's x axis, where the palm touches: off the wrist's axis, so the
    /// load turns the wrist too.
    pub fn static_torques_at(
        &self,
        q: &[f64; DOF],
        hand_force: DVec3,
        contact_offset: f64,
    ) -> [f64; DOF] {
        let k = self.fk(q);
        let contact = if contact_offset == 0.0 {
            k.tcp.translation
        } else {
            k.tcp.translation + k.tcp.matrix3.x_axis * contact_offset
        };
        let mut origins: Vec<DVec3> = k.joints.iter().map(|f| f.translation).collect();
        origins.push(k.tcp.translation);
        let com: Vec<DVec3> = (0..DOF)
            .map(|i| 0.5 * (origins[i] + origins[i + 1]))
            .collect();
        let mut tau = [0.0; DOF];
        for j in 0..DOF {
            let axis = k.joints[j].matrix3.z_axis;
            let pj = k.joints[j].translation;
            let mut t = 0.0;
            for i in j..DOF {
                let weight = DVec3::new(0.0, 0.0, -LINK_MASS[i] * GRAVITY);
                t -= axis.dot((com[i] - pj).cross(weight));
            }
            t -= axis.dot((contact - pj).cross(hand_force));
            tau[j] = t;
        }
        tau
    }
}

/// Inverse of a symmetric positive definite 3x3 matrix.
fn invert3(a: [[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let m = DMat3::from_cols_array_2d(&a).inverse();
    m.to_cols_array_2d()
}

/// A base frame hanging from a shoulder: joint 1 points down, base x points forward.
pub fn hanging_base(shoulder: DVec3, yaw: f64) -> DAffine3 {
    let rot = DMat3::from_rotation_z(yaw) * DMat3::from_rotation_x(std::f64::consts::PI);
    DAffine3::from_mat3_translation(rot, shoulder)
}

/// x³ as two products (what `powi(3)` compiles to today, written out so that no library
/// call can ever stand in).
fn cube(x: f64) -> f64 {
    x * x * x
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zero_pose_matches_the_published_geometry() {
        let arm = Arm {
            base: DAffine3::IDENTITY,
        };
        let k = arm.fk(&[0.0; DOF]);
        // At q = 0 the Panda's flange sits at (0.088, 0, 0.926) with the z axis pointing down.
        let f = k.flange.translation;
        assert!((f - DVec3::new(0.088, 0.0, 0.926)).length() < 1e-9, "{f}");
        assert!((k.flange.matrix3.z_axis - DVec3::NEG_Z).length() < 1e-9);
    }

    #[test]
    fn jacobian_matches_finite_differences() {
        let arm = Arm {
            base: hanging_base(DVec3::new(0.0, 0.2, 1.2), 0.1),
        };
        let q = [0.3, -0.4, 0.2, -2.0, 0.1, 1.7, 0.5];
        let k = arm.fk(&q);
        let j = Arm::jacobian(&k, k.tcp.translation);
        for i in 0..DOF {
            let mut qp = q;
            qp[i] += 1e-6;
            let dp = (arm.fk(&qp).tcp.translation - k.tcp.translation) / 1e-6;
            for r in 0..3 {
                assert!((dp[r] - j[r][i]).abs() < 1e-5, "joint {i} row {r}");
            }
        }
    }

    #[test]
    fn torques_hold_the_arm_and_react_to_loads() {
        let arm = Arm {
            base: DAffine3::IDENTITY,
        };
        // Upright (q = 0): gravity acts along every vertical axis; horizontal-lever joints carry torque.
        let q = [0.0, 0.5, 0.0, -1.5, 0.0, 1.5, 0.0];
        let t0 = arm.static_torques(&q, DVec3::ZERO);
        assert!(t0[0].abs() < 1e-9, "joint 1 is vertical: no gravity torque");
        assert!(t0[1].abs() > 1.0);
        // Pushing down on the hand adds -J^T F.
        let f = DVec3::new(0.0, 0.0, -20.0);
        let t1 = arm.static_torques(&q, f);
        let k = arm.fk(&q);
        let j = Arm::jacobian(&k, k.tcp.translation);
        for i in 0..DOF {
            let expect = t0[i] - (j[0][i] * f.x + j[1][i] * f.y + j[2][i] * f.z);
            assert!((t1[i] - expect).abs() < 1e-9);
        }
    }
}
