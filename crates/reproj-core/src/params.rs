//! Parameters of the reprojection methods, with the defaults of shared/DESIGN.md.

use crate::error::{ReprojError, Result};

/// Tile side used by every tiled kernel. 16×16 pixels of RGB8 output plus the per-pixel search
/// state stay inside L1 while being large enough that rayon's per-task overhead is negligible;
/// it is also the workgroup size of the GPU twin.
pub const TILE: usize = 16;

/// Options shared by the methods; each documents which methods read it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Params {
    /// `ε_e`: reprojection-error threshold of the main camera, in NDC units scaled so that 2.0 is
    /// the image's short side (REFERENCE.md §2.5). Default 0.002. (ours, forward_splat)
    pub eps_e: f32,
    /// `ε_z`: depth-similarity threshold of the main camera in NDC z units (a `[−1,1]` range, so a
    /// reversed-depth difference `ΔZ` counts as `2·|ΔZ|`). Default 0.001. (ours, forward_splat,
    /// backward_bidir)
    pub eps_z: f32,
    /// `ε_O`: motion-cancel threshold of Algorithm 2, 3-D NDC norm. Default 0.01. (ours)
    pub eps_o: f32,
    /// Factor applied to `ε_e` and `ε_z` for auxiliary cameras (they have ¼ the pixels).
    /// Default 4. (ours, forward_splat)
    pub aux_threshold_scale: f32,
    /// Half-width `W` of the `(2W+1)²` window search around the splat. Default 1 (3×3).
    pub window: usize,
    /// Fixed-point iterations after the splat initialisation. Default 3. (ours; backward_bidir
    /// uses its own count, [`Params::bidir_iterations`])
    pub fpi_iterations: usize,
    /// Fixed-point iterations of `backward_bidir` (seeds/001 uses 3).
    pub bidir_iterations: usize,
    /// `S = f_d / f_s`: dynamic-shadow subframes per server interval. Default 4. Must be 1..=16
    /// (2 bits each in a 32-bit field).
    pub shadow_subframes: usize,
    /// Apply dynamic shadows (eqs. 9–11). Default true. (ours, ours_extrapolate)
    pub use_shadows: bool,
    /// Use the auxiliary cameras of the frames. Default true. (ours, ours_extrapolate,
    /// forward_splat, timewarp)
    pub use_aux: bool,
    /// Blend the two frames by Algorithm 2 (second chance). Default true. (ours)
    pub blend: bool,
    /// `forward_splat` only: splat both frames instead of the newest one alone. Default false (the
    /// paper's baseline is unidirectional).
    pub splat_bidirectional: bool,
}

impl Default for Params {
    fn default() -> Self {
        Params {
            eps_e: 0.002,
            eps_z: 0.001,
            eps_o: 0.01,
            aux_threshold_scale: 4.0,
            window: 1,
            fpi_iterations: 3,
            bidir_iterations: 3,
            shadow_subframes: 4,
            use_shadows: true,
            use_aux: true,
            blend: true,
            splat_bidirectional: false,
        }
    }
}

fn bad(name: &str, value: impl ToString, expected: &str) -> ReprojError {
    ReprojError::BadOption {
        name: name.to_string(),
        value: value.to_string(),
        expected: expected.to_string(),
    }
}

impl Params {
    /// `ε_z` of the auxiliary cameras: `ε_z · aux_threshold_scale` (the one product every stage
    /// that compares auxiliary depths uses, so that they agree to the bit).
    pub fn eps_z_aux(&self) -> f32 {
        self.eps_z * self.aux_threshold_scale
    }

    /// Checks every option's domain.
    ///
    /// # Errors
    /// [`ReprojError::BadOption`] for the first option outside its domain.
    pub fn validate(&self) -> Result<()> {
        for (name, v) in [
            ("eps_e", self.eps_e),
            ("eps_z", self.eps_z),
            ("eps_o", self.eps_o),
            ("aux_threshold_scale", self.aux_threshold_scale),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(bad(name, v, "expected a finite value > 0"));
            }
        }
        if self.window > 8 {
            return Err(bad("window", self.window, "expected 0..=8"));
        }
        if self.fpi_iterations > 32 {
            return Err(bad(
                "fpi_iterations",
                self.fpi_iterations,
                "expected 0..=32",
            ));
        }
        if self.bidir_iterations > 32 {
            return Err(bad(
                "bidir_iterations",
                self.bidir_iterations,
                "expected 0..=32",
            ));
        }
        if !(1..=16).contains(&self.shadow_subframes) {
            return Err(bad(
                "shadow_subframes",
                self.shadow_subframes,
                "expected 1..=16",
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each option at the edge of its domain passes; one step past it is refused naming the
    /// option, its value and the domain.
    #[test]
    fn validate_names_the_option_outside_its_domain() {
        Params::default().validate().unwrap();
        type Set = fn(&mut Params, bool);
        let cases: [(&str, Set, &str, &str); 6] = [
            (
                "eps_e",
                |p, past| p.eps_e = if past { 0.0 } else { 1e-9 },
                "0",
                "> 0",
            ),
            (
                "window",
                |p, past| p.window = 8 + usize::from(past),
                "9",
                "0..=8",
            ),
            (
                "fpi_iterations",
                |p, past| p.fpi_iterations = 32 + usize::from(past),
                "33",
                "0..=32",
            ),
            (
                "bidir_iterations",
                |p, past| p.bidir_iterations = 32 + usize::from(past),
                "33",
                "0..=32",
            ),
            (
                "shadow_subframes",
                |p, past| p.shadow_subframes = 16 + usize::from(past),
                "17",
                "1..=16",
            ),
            (
                "shadow_subframes",
                |p, past| p.shadow_subframes = usize::from(!past),
                "0",
                "1..=16",
            ),
        ];
        for (name, set, value, domain) in cases {
            let mut p = Params::default();
            set(&mut p, false);
            p.validate()
                .unwrap_or_else(|e| panic!("{name} at its edge: {e}"));
            set(&mut p, true);
            match p.validate() {
                Err(ReprojError::BadOption {
                    name: n,
                    value: v,
                    expected,
                }) => {
                    assert_eq!((n.as_str(), v.as_str()), (name, value));
                    assert!(expected.contains(domain), "{expected}");
                }
                other => panic!("{name}: {other:?}"),
            }
        }
    }
}
