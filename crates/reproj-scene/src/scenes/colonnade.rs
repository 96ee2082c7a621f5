//! The built-in scene `colonnade`: a long hall of lathed columns with swinging banners and an
//! articulated runner (built by `runner`) that the camera follows (see [`crate::scenes`]).

use std::f64::consts::PI;

use super::{at, capsule, cuboid, finish, path, sun, swing_x};
use crate::anim::Anim;
use crate::material::Material;
use crate::material::Pattern::{Bricks, Checker, Noise, Tiles};
use crate::math::V3;
use crate::meshes;
use crate::scene::{Object, Scene, Variant};
use crate::shape::Shape;

/// An articulated runner made of boxes, capsules and a sphere, facing −z at `start` (its feet on
/// the ground at `y = start[1]`) and running along −z at `speed`; `stride` is the stride's angular
/// rate (rad/s). Returns the pelvis index.
fn runner(objects: &mut Vec<Object>, start: V3, speed: f64, stride: f64) -> usize {
    let skin = Material::matte(Noise, [0.85, 0.62, 0.5], [0.7, 0.45, 0.38], 8.0, 40);
    let shirt = Material::matte(Checker, [0.85, 0.2, 0.15], [0.95, 0.9, 0.85], 12.0, 41);
    let trousers = Material::matte(Tiles, [0.2, 0.25, 0.5], [0.1, 0.1, 0.2], 20.0, 42);
    let pelvis = objects.len();
    objects.push(
        Object::new(
            "runner pelvis",
            cuboid([0.16, 0.09, 0.1]),
            trousers,
            at([start[0], start[1] + 1.0, start[2]]),
        )
        .animated([
            Anim::Translate {
                velocity: [0.0, 0.0, -speed],
                acceleration: [0.0; 3],
            },
            Anim::Oscillate {
                amplitude: [0.0, 0.05, 0.0],
                rate: 2.0 * stride,
                phase: 0.0,
            },
        ]),
    );
    let torso = objects.len();
    objects.push(
        Object::new(
            "runner torso",
            Shape::Cuboid {
                min: [-0.18, 0.0, -0.1],
                max: [0.18, 0.55, 0.11],
            },
            shirt,
            at([0.0, 0.06, 0.0]),
        )
        .child_of(pelvis)
        .animated([swing_x(-0.2, 0.05, 2.0 * stride, 0.5)]),
    );
    objects.push(
        Object::new(
            "runner head",
            Shape::Sphere { radius: 0.12 },
            skin,
            at([0.0, 0.7, 0.0]),
        )
        .child_of(torso),
    );
    for (side, phase) in [(-1.0, 0.0), (1.0, PI)] {
        let upper = objects.len();
        objects.push(
            Object::new(
                "runner upper arm",
                capsule(0.28, 0.05),
                shirt,
                at([0.25 * side, 0.5, 0.0]),
            )
            .child_of(torso)
            .animated([swing_x(0.0, 0.9, stride, phase)]),
        );
        objects.push(
            Object::new(
                "runner forearm",
                capsule(0.26, 0.045),
                skin,
                at([0.0, -0.3, 0.0]),
            )
            .child_of(upper)
            .animated([swing_x(1.3, 0.3, stride, phase)]),
        );
        let thigh = objects.len();
        objects.push(
            Object::new(
                "runner thigh",
                capsule(0.42, 0.07),
                trousers,
                at([0.1 * side, -0.05, 0.0]),
            )
            .child_of(pelvis)
            .animated([swing_x(0.1, 0.75, stride, phase + PI)]),
        );
        objects.push(
            Object::new(
                "runner shin",
                capsule(0.42, 0.055),
                trousers,
                at([0.0, -0.44, 0.0]),
            )
            .child_of(thigh)
            .animated([swing_x(-0.7, 0.6, stride, phase + PI - 1.2)]),
        );
    }
    pelvis
}
/// `colonnade`: see the module docs.
pub fn colonnade(variant: Variant) -> Scene {
    let marble =
        Material::matte(Tiles, [0.86, 0.82, 0.74], [0.4, 0.36, 0.3], 1.0, 20).shiny(0.15, 40.0);
    let stone = Material::matte(Noise, [0.8, 0.74, 0.62], [0.62, 0.56, 0.46], 3.0, 21);
    let brick = Material::matte(Bricks, [0.66, 0.42, 0.3], [0.8, 0.76, 0.68], 2.5, 22);
    let cloth = [
        Material::matte(Checker, [0.7, 0.1, 0.12], [0.9, 0.75, 0.2], 6.0, 23),
        Material::matte(Checker, [0.1, 0.4, 0.2], [0.85, 0.85, 0.8], 6.0, 24),
        Material::matte(Checker, [0.15, 0.2, 0.6], [0.9, 0.6, 0.2], 6.0, 25),
    ];
    let mut o = vec![Object::new(
        "floor",
        Shape::Quad { half: [6.0, 24.0] },
        marble,
        at([0.0, 0.0, -10.0]),
    )];
    for side in [-1.0, 1.0] {
        o.push(Object::new(
            "side wall",
            cuboid([0.3, 4.5, 24.0]),
            brick,
            at([side * 6.3, 4.5, -10.0]),
        ));
    }
    o.push(Object::new(
        "end wall",
        cuboid([6.6, 4.5, 0.3]),
        brick,
        at([0.0, 4.5, -34.3]),
    ));
    let column = meshes::lathe(
        |s| {
            // Fluted look from a gentle entasis; the flutes come from the texture.
            (0.32 - 0.05 * s + 0.02 * (s * PI).sin(), 0.3 + 4.4 * s)
        },
        40,
        12,
    );
    let mut z = 4.0;
    while z > -30.0 {
        for x in [-3.2, 3.2] {
            o.push(Object::new(
                "column base",
                cuboid([0.45, 0.15, 0.45]),
                stone,
                at([x, 0.15, z]),
            ));
            o.push(Object::new(
                "column",
                column.clone(),
                stone,
                at([x, 0.0, z]),
            ));
            o.push(Object::new(
                "capital",
                cuboid([0.45, 0.15, 0.45]),
                stone,
                at([x, 4.85, z]),
            ));
        }
        z -= 4.0;
    }
    for x in [-3.2, 3.2] {
        o.push(Object::new(
            "architrave",
            cuboid([0.45, 0.3, 17.0]),
            stone,
            at([x, 5.3, -13.0]),
        ));
    }
    // Cross beams overhead, open between them so that the sun comes in.
    let mut z = 2.0;
    while z > -30.0 {
        o.push(Object::new(
            "beam",
            cuboid([6.0, 0.2, 0.25]),
            stone,
            at([0.0, 5.6, z]),
        ));
        z -= 4.0;
    }
    // Banners hanging between the side columns, swinging gently.
    let mut k = 0;
    let mut z = 2.0;
    while z > -30.0 {
        for x in [-4.6, 4.6] {
            o.push(
                Object::new(
                    "banner",
                    Shape::Cuboid {
                        min: [-0.02, -2.4, -0.7],
                        max: [0.02, 0.0, 0.7],
                    },
                    cloth[k % 3],
                    at([x, 5.0, z]),
                )
                .animated([Anim::Swing {
                    axis: [0.0, 0.0, 1.0],
                    offset: 0.0,
                    amplitude: 0.12,
                    rate: 1.7 + 0.1 * k as f64,
                    phase: k as f64,
                }]),
            );
            k += 1;
        }
        z -= 8.0;
    }
    runner(&mut o, [0.3, 0.0, 0.0], 4.0, 2.0 * PI * 1.4);
    let light = sun(58.0, 120.0, 0.03);
    let cam = path(
        |t| {
            let fz = -4.0 * t;
            (
                [0.9 + 0.3 * (0.8 * t).sin(), 1.75, fz + 4.2],
                [0.2, 1.1, fz - 2.0],
            )
        },
        0.03,
        0.03,
        22,
    );
    finish("colonnade", variant, o, light, [170, 200, 235], cam)
}
