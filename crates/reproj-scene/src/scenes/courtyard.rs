//! The built-in scene `courtyard`: a cobbled square between brick houses, with a rolling ball, a
//! cart, a swinging sign, a windmill and a circling drone (see [`crate::scenes`]).

use std::f64::consts::PI;

use super::{at, cuboid, finish, path, sun, swing_x, turned};
use crate::anim::Anim;
use crate::material::Material;
use crate::material::Pattern::{Bricks, Checker, Noise, Tiles};
use crate::math::Rigid;
use crate::meshes;
use crate::scene::{Object, Scene, Variant};
use crate::shape::Shape;

/// `courtyard`: see the module docs.
pub fn courtyard(variant: Variant) -> Scene {
    let cobbles = Material::matte(Tiles, [0.62, 0.58, 0.52], [0.3, 0.28, 0.25], 2.5, 1);
    let brick = Material::matte(Bricks, [0.7, 0.38, 0.28], [0.82, 0.8, 0.74], 2.0, 2);
    let plaster = Material::matte(Noise, [0.88, 0.84, 0.72], [0.7, 0.66, 0.56], 1.5, 3);
    let roof = Material::matte(Tiles, [0.45, 0.18, 0.12], [0.2, 0.1, 0.08], 4.0, 4);
    let wood = Material::matte(Noise, [0.55, 0.38, 0.22], [0.35, 0.22, 0.12], 6.0, 5);
    let grass = Material::matte(Noise, [0.32, 0.5, 0.2], [0.2, 0.35, 0.12], 3.0, 6);
    let ball =
        Material::matte(Checker, [0.95, 0.3, 0.2], [0.98, 0.88, 0.35], 8.0, 7).shiny(0.3, 30.0);
    let metal =
        Material::matte(Noise, [0.6, 0.62, 0.66], [0.45, 0.47, 0.5], 4.0, 8).shiny(0.5, 60.0);
    let mut o = vec![
        Object::new(
            "ground",
            Shape::Quad { half: [30.0, 30.0] },
            cobbles,
            Rigid::IDENTITY,
        ),
        Object::new(
            "lawn",
            cuboid([4.0, 0.02, 3.0]),
            grass,
            at([-8.0, 0.02, -6.0]),
        ),
    ];
    // Houses around the square: (centre x, z, half width x, half depth z, height, yaw).
    let houses = [
        (-13.0, -14.0, 4.0, 3.0, 5.0, 0.0),
        (-4.0, -16.0, 4.5, 3.0, 6.5, 0.0),
        (7.0, -15.0, 5.0, 3.5, 5.5, 0.0),
        (16.0, -4.0, 3.0, 5.0, 6.0, 0.0),
        (-17.0, 2.0, 3.0, 5.0, 5.0, 0.0),
        (15.0, 9.0, 3.0, 4.0, 4.5, 0.3),
    ];
    for (k, &(x, z, hx, hz, h, yaw)) in houses.iter().enumerate() {
        let wall = if k % 2 == 0 { brick } else { plaster };
        let base = turned([x, 0.0, z], [0.0, 1.0, 0.0], yaw);
        o.push(Object::new(
            "house",
            Shape::Cuboid {
                min: [-hx, 0.0, -hz],
                max: [hx, h, hz],
            },
            wall,
            base,
        ));
        // A gabled roof: two slabs tilted about the ridge, along x.
        for side in [-1.0, 1.0] {
            let slope: f64 = 0.6;
            let half_run = hz / slope.cos() * 0.5 + 0.3;
            o.push(Object::new(
                "roof",
                cuboid([hx + 0.3, 0.08, half_run]),
                roof,
                base.then(&turned(
                    [0.0, h + hz * slope.tan() * 0.5, side * hz * 0.5],
                    [1.0, 0.0, 0.0],
                    side * slope,
                )),
            ));
        }
    }
    // The well: a torus ring on a lathed drum, with a roof beam on two posts.
    o.push(Object::new(
        "well drum",
        meshes::lathe(|s| (1.0 + 0.05 * (s * PI).sin(), 0.8 * s), 40, 6),
        brick,
        at([2.0, 0.0, -4.0]),
    ));
    o.push(Object::new(
        "well rim",
        meshes::torus(1.0, 0.12, 48, 12),
        plaster,
        at([2.0, 0.8, -4.0]),
    ));
    for dx in [-1.05, 1.05] {
        o.push(Object::new(
            "well post",
            cuboid([0.08, 1.2, 0.08]),
            wood,
            at([2.0 + dx, 1.2, -4.0]),
        ));
    }
    o.push(Object::new(
        "well beam",
        cuboid([1.3, 0.08, 0.1]),
        wood,
        at([2.0, 2.45, -4.0]),
    ));
    // Barrels and crates.
    let barrel_shape = meshes::lathe(|s| (0.4 + 0.06 * (s * PI).sin(), 1.0 * s), 32, 8);
    for (k, &(x, z)) in [
        (-6.0, -10.5),
        (-5.1, -10.8),
        (-5.6, -9.8),
        (9.5, -9.0),
        (12.0, 2.0),
    ]
    .iter()
    .enumerate()
    {
        o.push(Object::new(
            "barrel",
            barrel_shape.clone(),
            wood,
            turned([x, 0.0, z], [0.0, 1.0, 0.0], k as f64),
        ));
    }
    for (k, &(x, y, z)) in [(11.0, 0.4, -8.0), (11.9, 0.4, -7.7), (11.4, 1.2, -7.9)]
        .iter()
        .enumerate()
    {
        o.push(Object::new(
            "crate",
            cuboid([0.4; 3]),
            Material::matte(
                Checker,
                [0.6, 0.45, 0.25],
                [0.45, 0.32, 0.16],
                5.0,
                10 + k as u64,
            ),
            turned([x, y, z], [0.0, 1.0, 0.0], 0.2 * k as f64),
        ));
    }
    // The fast ball: rolls along +x across the square in front of the camera.
    o.push(
        Object::new(
            "ball",
            Shape::Sphere { radius: 0.5 },
            ball,
            at([-10.0, 0.5, -2.0]),
        )
        .animated([Anim::Roll {
            direction: [1.0, 0.0, 0.15],
            radius: 0.5,
            speed: 5.0,
            acceleration: 0.0,
        }]),
    );
    // A cart moving toward the camera with spinning wheels (children).
    let cart = o.len();
    o.push(
        Object::new(
            "cart",
            Shape::Cuboid {
                min: [-0.6, 0.35, -1.0],
                max: [0.6, 0.9, 1.0],
            },
            wood,
            at([-3.0, 0.0, -11.0]),
        )
        .animated([Anim::Translate {
            velocity: [0.0, 0.0, 1.2],
            acceleration: [0.0, 0.0, 0.3],
        }]),
    );
    for (dx, dz) in [(-0.7, -0.6), (0.7, -0.6), (-0.7, 0.6), (0.7, 0.6)] {
        o.push(
            Object::new(
                "cart wheel",
                meshes::torus(0.28, 0.06, 24, 8),
                metal,
                turned([dx, 0.35, dz], [0.0, 0.0, 1.0], PI / 2.0),
            )
            .child_of(cart)
            // The wheel's own y axis is the axle (it was turned onto world x): the rolling angle is
            // distance / radius, with the cart's acceleration.
            .animated([Anim::Spin {
                axis: [0.0, 1.0, 0.0],
                rate: -1.2 / 0.34,
                acceleration: -0.3 / 0.34,
            }]),
        );
    }
    // A hanging sign swinging on a bracket of the second house.
    o.push(Object::new(
        "sign bracket",
        cuboid([0.05, 0.05, 0.6]),
        metal,
        at([-1.0, 3.5, -12.4]),
    ));
    o.push(
        Object::new(
            "sign",
            Shape::Cuboid {
                min: [-0.04, -0.9, -0.45],
                max: [0.04, -0.1, 0.45],
            },
            Material::matte(Checker, [0.2, 0.35, 0.7], [0.9, 0.85, 0.6], 6.0, 12),
            at([-1.0, 3.45, -11.9]),
        )
        .animated([swing_x(0.0, 0.35, 3.0, 0.0)]),
    );
    // A windmill: a hub spinning with four blades as children.
    o.push(Object::new(
        "mill pole",
        cuboid([0.12, 2.5, 0.12]),
        wood,
        at([9.0, 2.5, -10.0]),
    ));
    let hub = o.len();
    o.push(
        Object::new(
            "mill hub",
            Shape::Sphere { radius: 0.25 },
            metal,
            at([9.0, 5.0, -9.75]),
        )
        .animated([Anim::Spin {
            axis: [0.0, 0.0, 1.0],
            rate: 2.5,
            acceleration: 0.0,
        }]),
    );
    for k in 0..4 {
        o.push(
            Object::new(
                "mill blade",
                Shape::Cuboid {
                    min: [-0.2, 0.2, -0.03],
                    max: [0.2, 2.0, 0.03],
                },
                plaster,
                Rigid::rotation([0.0, 0.0, 1.0], k as f64 * PI / 2.0),
            )
            .child_of(hub),
        );
    }
    // A drone circling overhead around (0, 3.2, −5), bobbing.
    o.push(
        Object::new(
            "drone",
            cuboid([0.3, 0.08, 0.3]),
            metal,
            at([0.0, 3.2, -5.0]),
        )
        .animated([
            Anim::Circle {
                radius: 4.0,
                rate: 0.9,
                phase: 0.0,
            },
            Anim::Oscillate {
                amplitude: [0.0, 0.25, 0.0],
                rate: 4.0,
                phase: 0.0,
            },
        ]),
    );
    let light = sun(38.0, 35.0, 0.02);
    let cam = path(
        |t| {
            (
                [-1.5 + 0.9 * t, 1.7, 7.0 - 0.3 * t],
                [1.0 + 0.3 * t, 0.6, -4.0],
            )
        },
        0.04,
        0.035,
        11,
    );
    finish("courtyard", variant, o, light, [150, 190, 230], cam)
}
