//! Reflectance models and the radiometric model of the paper (eq. 9).
//!
//! Both models share one parameter set ([`BrdfParams`]): diffuse albedo `rho_d` and
//! specular albedo `rho_s` (linear RGB, dimensionless, in the capture's normalised
//! units), roughness `alpha_x`, `alpha_y` along the plane's x and y axes, and two
//! normal-offset angles. Every model gives the radiance reflected towards the camera
//! by a point light together with its analytic derivatives with respect to all ten
//! parameters, so that fitting never needs finite differences.
//!
//! Hot-path evaluation uses only dot products, `sqrt`, `exp` and `powi`: everything
//! that needs trigonometry (the normal and tangent frame and its derivatives) is
//! computed once per parameter set in [`Prepared`].

pub mod batch;
mod frame;
mod ggx;
mod ward;

pub use frame::ShadingFrame;
pub use ggx::Ggx;
pub use ward::Ward;

use serde::{Deserialize, Serialize};

use crate::geometry::Vec3;

/// Number of fitted parameters: rho_d (3), rho_s (3), alpha_x, alpha_y, theta_x, theta_y.
pub const N_PARAMS: usize = 10;

/// Parameters shared by all channels, in the order of [`RadianceGrad::d_shared`].
pub const SHARED_NAMES: [&str; 4] = ["alpha_x", "alpha_y", "normal_theta_x", "normal_theta_y"];

/// Parameters of one BRDF with a normal offset.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BrdfParams {
    /// Diffuse albedo, linear RGB.
    pub rho_d: [f64; 3],
    /// Specular albedo, linear RGB (for GGX: the normal-incidence Fresnel reflectance F0).
    pub rho_s: [f64; 3],
    /// Roughness along the tangent (plane +x), > 0.
    pub alpha_x: f64,
    /// Roughness along the bitangent (plane +y), > 0.
    pub alpha_y: f64,
    /// Normal tilt in the y-z plane (a rotation about the x axis), radians. The
    /// unnormalised normal is `(tan theta_y, -tan theta_x, 1)`.
    pub normal_theta_x: f64,
    /// Normal tilt in the x-z plane (a rotation about the y axis), radians.
    pub normal_theta_y: f64,
    /// Tangent rotation (the anisotropy direction), radians: `alpha_x` acts along the
    /// plane's +x axis (projected onto the surface) turned by this angle about the
    /// normal towards +y. 0 for materials whose grain runs along the plane's axes.
    /// Not one of the [`N_PARAMS`] solver parameters: fits search it per cluster and
    /// hold it fixed in each solve.
    #[serde(default)]
    pub tangent_rotation: f64,
}

impl Default for BrdfParams {
    /// The paper's initialisation for a grey surface: alpha = 0.1, flat normal.
    fn default() -> Self {
        Self {
            rho_d: [0.5; 3],
            rho_s: [0.05; 3],
            alpha_x: 0.1,
            alpha_y: 0.1,
            normal_theta_x: 0.0,
            normal_theta_y: 0.0,
            tangent_rotation: 0.0,
        }
    }
}

impl BrdfParams {
    /// Flat packing in the fitter's order:
    /// `[rho_d r g b, rho_s r g b, alpha_x, alpha_y, theta_x, theta_y]`.
    pub fn to_array(&self) -> [f64; N_PARAMS] {
        let [dr, dg, db] = self.rho_d;
        let [sr, sg, sb] = self.rho_s;
        [
            dr,
            dg,
            db,
            sr,
            sg,
            sb,
            self.alpha_x,
            self.alpha_y,
            self.normal_theta_x,
            self.normal_theta_y,
        ]
    }

    /// Inverse of [`to_array`](Self::to_array), with no tangent rotation.
    pub fn from_array(a: &[f64; N_PARAMS]) -> Self {
        Self::from_array_rotated(a, 0.0)
    }

    /// Inverse of [`to_array`](Self::to_array) with the given tangent rotation
    /// (radians), which `to_array` leaves out.
    pub fn from_array_rotated(a: &[f64; N_PARAMS], tangent_rotation: f64) -> Self {
        Self {
            rho_d: [a[0], a[1], a[2]],
            rho_s: [a[3], a[4], a[5]],
            alpha_x: a[6],
            alpha_y: a[7],
            normal_theta_x: a[8],
            normal_theta_y: a[9],
            tangent_rotation,
        }
    }

    /// The same lobe described with the tangent rotation in [0, pi): a half turn
    /// changes nothing, and a quarter turn swaps `alpha_x` and `alpha_y`, so the
    /// stored angle is reduced to [0, pi/2) with the alphas swapped where needed.
    pub fn canonical_rotation(mut self) -> Self {
        let half = std::f64::consts::FRAC_PI_2;
        let mut r = self.tangent_rotation.rem_euclid(std::f64::consts::PI);
        if !r.is_finite() {
            r = 0.0;
        }
        if r >= half {
            r -= half;
            std::mem::swap(&mut self.alpha_x, &mut self.alpha_y);
        }
        self.tangent_rotation = r;
        self
    }

    /// The unit surface normal in plane coordinates.
    pub fn normal(&self) -> Vec3 {
        ShadingFrame::new(self.normal_theta_x, self.normal_theta_y).n
    }

    /// Normal-offset angles of a unit normal with positive z.
    pub fn angles_from_normal(n: Vec3) -> (f64, f64) {
        let z = n.z.max(1e-9);
        ((-n.y / z).atan(), (n.x / z).atan())
    }

    /// Whether the parameters satisfy the constraints of eq. (11) (per channel
    /// `rho_d, rho_s >= 0`, `rho_d + rho_s <= 1`, `alpha > 0`) and are finite.
    pub fn is_physical(&self) -> bool {
        let arr = self.to_array();
        arr.iter().all(|v| v.is_finite())
            && (0..3).all(|c| {
                self.rho_d[c] >= 0.0
                    && self.rho_s[c] >= 0.0
                    && self.rho_d[c] + self.rho_s[c] <= 1.0 + 1e-9
            })
            && self.alpha_x > 0.0
            && self.alpha_y > 0.0
            && self.tangent_rotation.is_finite()
    }
}

/// A parameter set with its shading frame precomputed; build once, evaluate many times.
#[derive(Debug, Clone, Copy)]
pub struct Prepared {
    /// The parameters.
    pub params: BrdfParams,
    /// Normal, tangent, bitangent and their derivatives.
    pub frame: ShadingFrame,
}

impl Prepared {
    /// Parameters with the normal given as a unit vector (renderers sample normal maps);
    /// evaluation uses `frame`, so the angle fields of `params` are ignored.
    pub fn from_normal(params: BrdfParams, n: Vec3) -> Self {
        Self {
            params,
            frame: ShadingFrame::from_normal(n).rotated(params.tangent_rotation),
        }
    }

    /// As [`from_normal`](Self::from_normal) but without the frame's derivatives: for
    /// [`BrdfModel::brdf`] and [`BrdfModel::radiance`] only, never for `radiance_grad`.
    pub fn for_evaluation(params: BrdfParams, n: Vec3) -> Self {
        Self {
            params,
            frame: ShadingFrame::for_evaluation(n).rotated(params.tangent_rotation),
        }
    }

    /// Precompute the frame of `params`.
    pub fn new(params: BrdfParams) -> Self {
        Self {
            params,
            frame: ShadingFrame::new(params.normal_theta_x, params.normal_theta_y)
                .rotated(params.tangent_rotation),
        }
    }
}

/// One observation's geometry: unit directions from the surface point to the light and
/// to the camera, in plane coordinates, the squared light distance (cm^2) and the room
/// light recorded with it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LightView {
    /// Unit direction to the light.
    pub light: Vec3,
    /// Unit direction to the camera.
    pub view: Vec3,
    /// Squared distance to the light, cm^2.
    pub light_dist2: f64,
    /// Room light, as irradiance per unit light intensity (cm^-2, the units of
    /// `cos(theta_i) / r^2`): it adds `I * rho_d / pi * ambient` to the radiance, the
    /// light a uniformly lit room adds to a Lambertian surface. 0 for a point light
    /// alone (every rendering under a new light).
    pub ambient: f64,
}

impl LightView {
    /// From a surface point and the light and camera positions (cm).
    pub fn from_points(surface: Vec3, light_pos: Vec3, camera_pos: Vec3) -> Self {
        let dl = light_pos - surface;
        let dv = camera_pos - surface;
        let r2 = dl.norm_squared().max(1e-12);
        Self {
            light: dl / r2.sqrt(),
            view: dv / dv.norm().max(1e-12),
            light_dist2: r2,
            ambient: 0.0,
        }
    }

    /// The same geometry with room light `ambient` (see [`Self::ambient`]).
    pub fn with_ambient(self, ambient: f64) -> Self {
        Self { ambient, ..self }
    }
}

/// Radiance and its derivatives for one observation. Channel-wise parameters (rho_d,
/// rho_s) only affect their own channel, so one number per channel suffices.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct RadianceGrad {
    /// Radiance per channel.
    pub value: [f64; 3],
    /// d value[c] / d rho_d[c].
    pub d_rho_d: [f64; 3],
    /// d value[c] / d rho_s[c].
    pub d_rho_s: [f64; 3],
    /// d value[c] / d (alpha_x, alpha_y, theta_x, theta_y).
    pub d_shared: [[f64; 3]; 4],
}

/// A reflectance model under the point-light radiometry of eq. (9):
/// `L = I * f(l, v) * cos(theta_i) / r^2` per channel, plus the room light
/// `I * rho_d / pi * ambient` ([`LightView::ambient`]), zero when the light or the
/// camera is below the (offset) surface.
pub trait BrdfModel: Sync + Send {
    /// Short name used in files and on the command line (`ward`, `ggx`).
    fn name(&self) -> &'static str;

    /// Which model this is (fast paths exist for some).
    fn kind(&self) -> ModelKind;

    /// The BRDF value per channel (1/sr) for unit directions.
    fn brdf(&self, p: &Prepared, light: Vec3, view: Vec3) -> [f64; 3];

    /// Reflected radiance for a light of intensity `intensity` (capture units * cm^2).
    fn radiance(&self, p: &Prepared, obs: &LightView, intensity: f64) -> [f64; 3] {
        let f = self.brdf(p, obs.light, obs.view);
        let cos_i = obs.light.dot(&p.frame.n);
        let cos_r = obs.view.dot(&p.frame.n);
        if cos_i <= 0.0 || cos_r <= 0.0 {
            return [0.0; 3];
        }
        let g = intensity * cos_i / obs.light_dist2;
        let a = intensity * obs.ambient / std::f64::consts::PI;
        std::array::from_fn(|c| g * f[c] + a * p.params.rho_d[c])
    }

    /// Radiance and its analytic derivatives.
    fn radiance_grad(&self, p: &Prepared, obs: &LightView, intensity: f64) -> RadianceGrad;

    /// Radiance for many observations at once (structure of arrays); the default loops
    /// over [`radiance`](Self::radiance), which the compiler inlines.
    fn radiance_batch(
        &self,
        p: &Prepared,
        obs: &[LightView],
        intensity: f64,
        out: &mut [[f64; 3]],
    ) {
        for (o, r) in obs.iter().zip(out.iter_mut()) {
            *r = self.radiance(p, o, intensity);
        }
    }
}

/// Which model to use, as named on the command line and in files.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum ModelKind {
    /// Anisotropic Ward (paper eq. 10).
    #[default]
    Ward,
    /// Anisotropic GGX / Cook-Torrance with Schlick Fresnel.
    Ggx,
}

impl ModelKind {
    /// The model object.
    pub fn model(self) -> &'static dyn BrdfModel {
        match self {
            Self::Ward => &Ward,
            Self::Ggx => &Ggx,
        }
    }
}

#[cfg(test)]
mod tests;
