//! The built-in scene `lab`: an open-topped room with a torus knot, a gear, a torus, a robot arm
//! and balls on a rail under a swinging light (see [`crate::scenes`]).

use std::f64::consts::PI;

use super::{at, cuboid, finish, path, sun, swing_x, turned, upright_capsule};
use crate::anim::Anim;
use crate::material::Material;
use crate::material::Pattern::{Checker, Noise, Tiles};
use crate::math::Rigid;
use crate::meshes;
use crate::scene::{Light, Object, Scene, Variant};
use crate::shape::Shape;

/// `lab`: see the module docs.
pub fn lab(variant: Variant) -> Scene {
    let floor = Material::matte(Checker, [0.85, 0.85, 0.82], [0.25, 0.27, 0.3], 1.0, 30);
    let wall = Material::matte(Tiles, [0.75, 0.8, 0.82], [0.4, 0.42, 0.45], 2.0, 31);
    let steel =
        Material::matte(Noise, [0.62, 0.64, 0.68], [0.42, 0.44, 0.5], 5.0, 32).shiny(0.6, 80.0);
    let orange =
        Material::matte(Checker, [0.95, 0.5, 0.1], [0.2, 0.2, 0.22], 10.0, 33).shiny(0.3, 30.0);
    let teal = Material::matte(Noise, [0.1, 0.6, 0.6], [0.05, 0.3, 0.4], 6.0, 34).shiny(0.4, 50.0);
    let table = Material::matte(Noise, [0.5, 0.36, 0.22], [0.36, 0.24, 0.14], 4.0, 35);
    let mut o = vec![
        Object::new(
            "floor",
            Shape::Quad { half: [7.0, 5.0] },
            floor,
            Rigid::IDENTITY,
        ),
        Object::new(
            "back wall",
            cuboid([7.0, 2.25, 0.15]),
            wall,
            at([0.0, 2.25, -5.15]),
        ),
        Object::new(
            "left wall",
            cuboid([0.15, 2.25, 5.0]),
            wall,
            at([-7.15, 2.25, 0.0]),
        ),
        Object::new(
            "right wall",
            cuboid([0.15, 2.25, 5.0]),
            wall,
            at([7.15, 2.25, 0.0]),
        ),
        Object::new(
            "table",
            cuboid([2.4, 0.05, 1.2]),
            table,
            at([0.0, 0.85, -1.5]),
        ),
    ];
    for (x, z) in [(-2.2, -2.5), (2.2, -2.5), (-2.2, -0.5), (2.2, -0.5)] {
        o.push(Object::new(
            "table leg",
            cuboid([0.05, 0.4, 0.05]),
            steel,
            at([x, 0.4, z]),
        ));
    }
    o.push(
        Object::new(
            "torus knot",
            meshes::torus_knot(2.0, 3.0, 0.45, 0.09, 256, 16),
            orange,
            at([-1.2, 1.55, -1.6]),
        )
        .animated([Anim::Spin {
            axis: [0.3, 1.0, 0.2],
            rate: 1.6,
            acceleration: 0.0,
        }]),
    );
    o.push(
        Object::new(
            "gear",
            meshes::gear(0.45, 0.12, 14, 168),
            steel,
            turned([1.3, 1.45, -2.0], [1.0, 0.0, 0.0], PI / 2.0),
        )
        .animated([Anim::Spin {
            axis: [0.0, 1.0, 0.0],
            rate: 3.0,
            acceleration: 1.5,
        }]),
    );
    o.push(
        Object::new(
            "torus",
            meshes::torus(0.3, 0.1, 48, 16),
            teal,
            turned([0.6, 1.1, -0.9], [1.0, 0.0, 0.0], 0.4),
        )
        .animated([
            Anim::Oscillate {
                amplitude: [0.9, 0.0, 0.0],
                rate: 1.8,
                phase: 0.0,
            },
            Anim::Spin {
                axis: [0.0, 0.0, 1.0],
                rate: 2.2,
                acceleration: 0.0,
            },
        ]),
    );
    // A robot arm: base turning, upper arm and forearm swinging, a two-finger gripper.
    let base = o.len();
    o.push(
        Object::new(
            "arm base",
            upright_capsule(0.6, 0.22),
            orange,
            at([4.0, 0.2, -2.5]),
        )
        .animated([Anim::Swing {
            axis: [0.0, 1.0, 0.0],
            offset: 0.5,
            amplitude: 1.0,
            rate: 1.1,
            phase: 0.0,
        }]),
    );
    let upper = o.len();
    o.push(
        Object::new(
            "arm upper",
            upright_capsule(1.1, 0.11),
            steel,
            at([0.0, 0.75, 0.0]),
        )
        .child_of(base)
        .animated([swing_x(-0.5, 0.35, 1.7, 0.3)]),
    );
    let fore = o.len();
    o.push(
        Object::new(
            "arm fore",
            upright_capsule(0.9, 0.08),
            orange,
            at([0.0, 1.1, 0.0]),
        )
        .child_of(upper)
        .animated([swing_x(-1.1, 0.5, 2.3, 1.0)]),
    );
    for side in [-1.0, 1.0] {
        o.push(
            Object::new(
                "gripper finger",
                Shape::Cuboid {
                    min: [-0.025, 0.0, -0.05],
                    max: [0.025, 0.22, 0.05],
                },
                steel,
                at([0.08 * side, 0.95, 0.0]),
            )
            .child_of(fore)
            .animated([Anim::Oscillate {
                amplitude: [0.04 * side, 0.0, 0.0],
                rate: 4.0,
                phase: 0.0,
            }]),
        );
    }
    // Balls accelerating along a rail on the left.
    o.push(Object::new(
        "rail",
        cuboid([0.05, 0.5, 4.0]),
        steel,
        at([-5.0, 0.5, -0.5]),
    ));
    for k in 0..3 {
        o.push(
            Object::new(
                "rail ball",
                Shape::Sphere { radius: 0.22 },
                Material::matte(Checker, [0.9, 0.9, 0.9], [0.8, 0.1, 0.3], 10.0, 36 + k),
                at([-5.0, 1.22, -3.5 + 0.9 * k as f64]),
            )
            .animated([Anim::Roll {
                direction: [0.0, 0.0, 1.0],
                radius: 0.22,
                speed: 0.3,
                acceleration: 0.35 + 0.05 * k as f64,
            }]),
        );
    }
    let light = Light {
        swing: 0.7,
        swing_rate: 0.9,
        elevation_swing: 0.12,
        angular_radius: 0.09,
        ..sun(50.0, 30.0, 0.09)
    };
    let cam = path(
        |t| {
            let a = -0.5 + 0.25 * t;
            (
                [5.0 * a.sin(), 2.0 + 0.1 * t, -1.5 + 5.0 * a.cos()],
                [0.0, 1.1, -1.6],
            )
        },
        0.03,
        0.03,
        33,
    );
    finish("lab", variant, o, light, [60, 64, 72], cam)
}
