//! The towel: a square particle grid with position-based dynamics (distance constraints
//! for stretch, shear and bending), gravity, friction, and collisions with the body and
//! the mattress. Grasped particles move rigidly with the hand; released, they fall and stay.

use glam::{DAffine3, DVec3};

use crate::math::{cos, sin};
use crate::shapes::{Mesh, Shape};

const GRAVITY: DVec3 = DVec3::new(0.0, 0.0, -9.81);
const MARGIN: f64 = 0.006;
const ITERATIONS: usize = 8;
const DAMPING: f64 = 0.985;
/// Friction coefficients of towel on fabric and sheets (static, kinetic).
const STATIC_FRICTION: f64 = 1.0;
const KINETIC_FRICTION: f64 = 0.6;

#[derive(Clone, Debug)]
pub struct Cloth {
    pub n: usize,
    pub pos: Vec<DVec3>,
    prev: Vec<DVec3>,
    constraints: Vec<(usize, usize, f64)>,
    /// Grasped particles and their offsets in the hand frame.
    pins: Vec<(usize, DVec3)>,
}

impl Cloth {
    /// An `n` x `n` square towel of side `size`, flat at `center`, rotated by `yaw`.
    pub fn new(center: DVec3, yaw: f64, size: f64, n: usize) -> Self {
        let step = size / (n - 1) as f64;
        let (c, s) = (cos(yaw), sin(yaw));
        let mut pos = Vec::with_capacity(n * n);
        for i in 0..n {
            for j in 0..n {
                let (u, v) = (i as f64 * step - size / 2.0, j as f64 * step - size / 2.0);
                pos.push(center + DVec3::new(c * u - s * v, s * u + c * v, 0.0));
            }
        }
        let mut constraints = Vec::new();
        let mut link = |a: usize, b: usize, pos: &[DVec3]| {
            constraints.push((a, b, (pos[a] - pos[b]).length()))
        };
        for i in 0..n {
            for j in 0..n {
                let k = i * n + j;
                if j + 1 < n {
                    link(k, k + 1, &pos);
                }
                if i + 1 < n {
                    link(k, k + n, &pos);
                }
                if i + 1 < n && j + 1 < n {
                    link(k, k + n + 1, &pos);
                    link(k + 1, k + n, &pos);
                }
                if j + 2 < n {
                    link(k, k + 2, &pos);
                }
                if i + 2 < n {
                    link(k, k + 2 * n, &pos);
                }
            }
        }
        Self {
            n,
            prev: pos.clone(),
            pos,
            constraints,
            pins: Vec::new(),
        }
    }

    pub fn is_grasped(&self) -> bool {
        !self.pins.is_empty()
    }

    /// Grasps the particles within `radius` of the hand (at least the nearest one).
    pub fn grasp(&mut self, hand: &DAffine3, radius: f64) {
        let p = hand.translation;
        let nearest = (0..self.pos.len())
            .min_by(|&a, &b| {
                (self.pos[a] - p)
                    .length()
                    .total_cmp(&(self.pos[b] - p).length())
            })
            .expect("a towel has particles");
        let inv = hand.inverse();
        self.pins = (0..self.pos.len())
            .filter(|&i| i == nearest || (self.pos[i] - p).length() < radius)
            .map(|i| (i, inv.transform_point3(self.pos[i])))
            .collect();
    }

    pub fn release(&mut self) {
        self.pins.clear();
    }

    /// Advances `dt` seconds in `substeps`; the grasped particles follow `hand`.
    pub fn step(
        &mut self,
        dt: f64,
        substeps: usize,
        colliders: &[Shape],
        mattress_top: f64,
        hand: Option<&DAffine3>,
    ) {
        let h = dt / substeps as f64;
        let mut pinned = vec![false; self.pos.len()];
        for &(i, _) in &self.pins {
            pinned[i] = true;
        }
        for _ in 0..substeps {
            for i in 0..self.pos.len() {
                if pinned[i] {
                    continue;
                }
                let v = (self.pos[i] - self.prev[i]) * DAMPING;
                self.prev[i] = self.pos[i];
                self.pos[i] += v + GRAVITY * h * h;
            }
            if let Some(hand) = hand {
                for &(i, offset) in &self.pins {
                    let target = hand.transform_point3(offset);
                    self.prev[i] = self.pos[i];
                    self.pos[i] = target;
                }
            }
            for _ in 0..ITERATIONS {
                for &(a, b, rest) in &self.constraints {
                    let (wa, wb) = (
                        if pinned[a] { 0.0 } else { 1.0 },
                        if pinned[b] { 0.0 } else { 1.0 },
                    );
                    if wa + wb == 0.0 {
                        continue;
                    }
                    let d = self.pos[b] - self.pos[a];
                    let len = d.length();
                    if len < 1e-12 {
                        continue;
                    }
                    let corr = d * ((len - rest) / (len * (wa + wb)));
                    self.pos[a] += corr * wa;
                    self.pos[b] -= corr * wb;
                }
                for i in 0..self.pos.len() {
                    if !pinned[i] {
                        self.collide(i, colliders, mattress_top);
                    }
                }
            }
        }
    }

    /// Pushes particle i out of the colliders and the mattress, with position-level
    /// friction: the substep's tangential displacement is cancelled while it is within the
    /// static friction cone of the penetration depth, and reduced beyond it.
    fn collide(&mut self, i: usize, colliders: &[Shape], mattress_top: f64) {
        let before = self.pos[i];
        let mut normal: Option<DVec3> = None;
        for s in colliders {
            if let Some((p, n)) = s.push_out(self.pos[i], MARGIN) {
                self.pos[i] = p;
                normal = Some(n);
            }
        }
        if self.pos[i].z < mattress_top + MARGIN {
            self.pos[i].z = mattress_top + MARGIN;
            normal = Some(DVec3::Z);
        }
        let Some(n) = normal else { return };
        let depth = (self.pos[i] - before).length();
        let moved = self.pos[i] - self.prev[i];
        let tangential = moved - n * moved.dot(n);
        let slide = tangential.length();
        if slide < STATIC_FRICTION * depth {
            self.pos[i] -= tangential;
        } else if slide > 0.0 {
            self.pos[i] -= tangential * (KINETIC_FRICTION * depth / slide).min(1.0);
        }
    }

    /// Mean particle position.
    pub fn centroid(&self) -> DVec3 {
        self.pos.iter().copied().sum::<DVec3>() / self.pos.len() as f64
    }

    /// Largest distance between a grasped particle and where the hand holds it.
    pub fn grip_error(&self, hand: &DAffine3) -> f64 {
        self.pins
            .iter()
            .map(|&(i, off)| (self.pos[i] - hand.transform_point3(off)).length())
            .fold(0.0, f64::max)
    }

    /// The index of the particle nearest to the robot (smallest world x) on the towel's edge,
    /// midway along that edge: where a hand grasps it.
    pub fn grasp_point(&self) -> DVec3 {
        let n = self.n;
        let edges = [
            (0..n).collect::<Vec<_>>(),
            (0..n).map(|j| (n - 1) * n + j).collect(),
            (0..n).map(|i| i * n).collect(),
            (0..n).map(|i| i * n + n - 1).collect(),
        ];
        let mean_x =
            |e: &Vec<usize>| e.iter().map(|&i| self.pos[i].x).sum::<f64>() / e.len() as f64;
        let edge = edges
            .iter()
            .min_by(|a, b| mean_x(a).total_cmp(&mean_x(b)))
            .expect("four edges");
        self.pos[edge[n / 2]]
    }

    /// A triangle mesh of the towel (render double-sided).
    pub fn mesh(&self) -> Mesh {
        let n = self.n;
        let mut m = Mesh::default();
        for i in 0..n {
            for j in 0..n {
                let at = |ii: usize, jj: usize| self.pos[ii.min(n - 1) * n + jj.min(n - 1)];
                let du = at(i + 1, j) - at(i.saturating_sub(1), j);
                let dv = at(i, j + 1) - at(i, j.saturating_sub(1));
                let mut normal = du.cross(dv).normalize_or_zero();
                if normal.z < 0.0 {
                    normal = -normal;
                }
                m.positions.push(self.pos[i * n + j]);
                m.normals.push(normal);
            }
        }
        for i in 0..n - 1 {
            for j in 0..n - 1 {
                let k = (i * n + j) as u32;
                let n32 = n as u32;
                m.indices.push([k, k + 1, k + n32]);
                m.indices.push([k + 1, k + n32 + 1, k + n32]);
            }
        }
        m
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DMat3;

    #[test]
    fn drapes_over_a_body_follows_the_hand_and_stays_after_release() {
        let body = [Shape::Ellipsoid {
            c: DVec3::new(0.0, 0.0, 0.1),
            rot: DMat3::IDENTITY,
            radii: DVec3::new(0.2, 0.3, 0.1),
        }];
        let mut towel = Cloth::new(DVec3::new(0.0, 0.0, 0.25), 0.3, 0.3, 11);
        for _ in 0..30 {
            towel.step(0.1, 8, &body, 0.0, None);
        }
        let rest = towel.centroid();
        assert!(rest.z > 0.05 && rest.z < 0.22, "draped {rest}");
        for p in &towel.pos {
            assert!(
                body[0].sdf(*p) > -0.002 && p.z >= 0.0,
                "inside the body: {p}"
            );
        }
        // Grasp the middle and carry the towel 20 cm.
        let mut hand = DAffine3::from_translation(towel.pos[5 * 11 + 5] + DVec3::Z * 0.01);
        towel.grasp(&hand, 0.035);
        for k in 0..20 {
            hand.translation += DVec3::new(0.01, 0.0, 0.005 * (k % 2) as f64);
            towel.step(0.1, 8, &body, 0.0, Some(&hand));
            assert!(towel.grip_error(&hand) < 1e-9);
        }
        assert!((towel.centroid().x - rest.x) > 0.1);
        towel.release();
        for _ in 0..20 {
            towel.step(0.1, 8, &body, 0.0, None);
        }
        let settled = towel.centroid();
        for _ in 0..20 {
            towel.step(0.1, 8, &body, 0.0, None);
        }
        assert!(
            (towel.centroid() - settled).length() < 0.01,
            "keeps moving after release"
        );
    }
}
