//! The VolPack side, through the C driver in `csrc/vpdriver.c` (compiled by build.rs when
//! VolPack is installed). Without VolPack every constructor reports [`MISSING`].

use crate::scenes::{Appearance, Loaded};

/// How to get VolPack, printed when the binary was built without it.
pub const MISSING: &str = "VolPack is not built in: install Debian's libvolpack1-dev \
(`apt-get install -y libvolpack1-dev`, or set VOLPACK_DIR to a prefix with \
include/volpack.h and lib/libvolpack.a), then rebuild with \
`cargo build --release -p shearwarp-bench`. Running the shearwarp side only.";

/// True when the driver was compiled in.
pub const AVAILABLE: bool = cfg!(has_volpack);

/// Image-space shift (pixels, x right, y down) applied to VolPack's view so that its
/// pixel centres line up with shearwarp's and the reference's (pixel `x` covers
/// `x..x+1`, sampled at `x + 0.5`): VolPack's warp samples pixel `x` of its y-up image
/// at coordinate `x`, so its picture sits half a pixel right of and above ours. The
/// value is also the PSNR optimum over a ±0.75-pixel grid on brainsmall and
/// mr_head_colin27 at 256² (37.2 / 37.4 dB against 35.3 / 34.0 dB unshifted).
pub const PIXEL_OFFSET: [f64; 2] = [-0.5, 0.5];

/// Everything the driver needs besides the voxels.
#[cfg_attr(not(has_volpack), allow(dead_code))]
pub struct Setup {
    pub dims: [usize; 3],
    pub spacing: [f64; 3],
    pub opacity: [f32; 256],
    pub min_opacity: f64,
    pub materials: Vec<[f32; 3]>,
    pub weights: Vec<f32>,
    pub ka: f64,
    pub kd: f64,
    pub ks: f64,
    pub shininess: f64,
    pub light: [f64; 3],
    pub ert: f64,
    pub pixel_offset: [f64; 2],
}

impl Setup {
    /// The benchmark's appearance in VolPack's terms.
    pub fn new(vol: &Loaded, look: &Appearance) -> Result<Self, Box<dyn std::error::Error>> {
        let (materials, weights) = look.materials();
        Ok(Setup {
            dims: vol.raw.dims,
            spacing: vol.raw.spacing,
            opacity: look.opacity_table()?,
            min_opacity: look.volpack_min_opacity(),
            materials,
            weights,
            ka: look.ka,
            kd: look.kd,
            ks: look.ks,
            shininess: look.shininess,
            light: look.light,
            ert: look.ert,
            pixel_offset: PIXEL_OFFSET,
        })
    }
}

#[cfg(has_volpack)]
mod imp {
    use super::Setup;
    use std::ffi::{c_char, c_double, c_float, c_int, c_long, c_uchar, CStr};
    use std::ptr::NonNull;

    #[repr(C)]
    struct VpbParams {
        dims: [c_int; 3],
        spacing: [c_double; 3],
        opacity: *const c_float,
        min_opacity: c_double,
        materials: c_int,
        material_rgb: *const c_float,
        weights: *const c_float,
        ka: c_double,
        kd: c_double,
        ks: c_double,
        shininess: c_double,
        light: [c_double; 3],
        max_ray_opacity: c_double,
        pixel_offset: [c_double; 2],
    }

    #[repr(C)]
    struct VpbScene {
        _private: [u8; 0],
    }

    extern "C" {
        fn vpb_create(
            p: *const VpbParams,
            data: *const c_uchar,
            out: *mut *mut VpbScene,
            preprocess_ms: *mut c_double,
        ) -> c_int;
        fn vpb_render(
            s: *mut VpbScene,
            rx: c_double,
            ry: c_double,
            width: c_int,
            height: c_int,
            rgb: *mut c_uchar,
            render_ms: *mut c_double,
        ) -> c_int;
        fn vpb_classified_bytes(s: *const VpbScene) -> c_long;
        fn vpb_destroy(s: *mut VpbScene);
        fn vpb_error_string(code: c_int) -> *const c_char;
    }

    fn error(code: c_int) -> String {
        // SAFETY: vpb_error_string returns a pointer to a static NUL-terminated string
        // for every code.
        let msg = unsafe { CStr::from_ptr(vpb_error_string(code)) };
        format!("VolPack: {} (code {code})", msg.to_string_lossy())
    }

    /// A classified VolPack volume with its rendering context.
    pub struct VolPack {
        scene: NonNull<VpbScene>,
    }

    impl VolPack {
        /// Classifies `data`; returns the scene and the preprocessing time in ms.
        pub fn new(setup: &Setup, data: &[u8]) -> Result<(Self, f64), String> {
            let m = setup.materials.len();
            let n: usize = setup.dims.iter().product();
            if data.len() != n || setup.weights.len() != 256 * m || m == 0 {
                return Err("VolPack: inconsistent setup".into());
            }
            let to_int = |d: usize| c_int::try_from(d).map_err(|_| "VolPack: volume too large");
            let rgb: Vec<f32> = setup.materials.iter().flatten().copied().collect();
            let params = VpbParams {
                dims: [
                    to_int(setup.dims[0])?,
                    to_int(setup.dims[1])?,
                    to_int(setup.dims[2])?,
                ],
                spacing: setup.spacing,
                opacity: setup.opacity.as_ptr(),
                min_opacity: setup.min_opacity,
                materials: to_int(m)?,
                material_rgb: rgb.as_ptr(),
                weights: setup.weights.as_ptr(),
                ka: setup.ka,
                kd: setup.kd,
                ks: setup.ks,
                shininess: setup.shininess,
                light: setup.light,
                max_ray_opacity: setup.ert,
                pixel_offset: setup.pixel_offset,
            };
            let mut out: *mut VpbScene = std::ptr::null_mut();
            let mut ms = 0.0;
            // SAFETY: every pointer in `params` points into live buffers of the sizes the
            // driver reads (256 opacities, 3·m colours, 256·m weights, n voxels, checked
            // above); the driver copies what it keeps.
            let code = unsafe { vpb_create(&params, data.as_ptr(), &mut out, &mut ms) };
            if code != 0 {
                return Err(error(code));
            }
            let scene = NonNull::new(out).ok_or("VolPack: driver returned no scene")?;
            Ok((VolPack { scene }, ms))
        }

        /// Renders one view into `rgb` (width·height·3 bytes, row 0 at the top); returns
        /// the render time in ms as measured by the driver.
        pub fn render(
            &mut self,
            rx: f64,
            ry: f64,
            width: usize,
            height: usize,
            rgb: &mut [u8],
        ) -> Result<f64, String> {
            if rgb.len() != width * height * 3 {
                return Err("VolPack: image buffer has the wrong size".into());
            }
            let w = c_int::try_from(width).map_err(|_| "VolPack: image too wide")?;
            let h = c_int::try_from(height).map_err(|_| "VolPack: image too tall")?;
            let mut ms = 0.0;
            // SAFETY: the scene is live (owned by self) and `rgb` holds width·height·3
            // bytes, which is what the driver writes.
            let code =
                unsafe { vpb_render(self.scene.as_ptr(), rx, ry, w, h, rgb.as_mut_ptr(), &mut ms) };
            if code != 0 {
                return Err(error(code));
            }
            Ok(ms)
        }

        /// Bytes of VolPack's three run-length encoded copies.
        pub fn classified_bytes(&self) -> usize {
            // SAFETY: the scene is live.
            let b = unsafe { vpb_classified_bytes(self.scene.as_ptr()) };
            usize::try_from(b).unwrap_or(0)
        }
    }

    impl Drop for VolPack {
        fn drop(&mut self) {
            // SAFETY: the scene came from vpb_create and is destroyed exactly once.
            unsafe { vpb_destroy(self.scene.as_ptr()) }
        }
    }
}

#[cfg(not(has_volpack))]
mod imp {
    use super::{Setup, MISSING};

    /// Stand-in when VolPack is not installed: construction always fails.
    pub struct VolPack {
        never: std::convert::Infallible,
    }

    impl VolPack {
        pub fn new(_setup: &Setup, _data: &[u8]) -> Result<(Self, f64), String> {
            Err(MISSING.into())
        }

        pub fn render(
            &mut self,
            _rx: f64,
            _ry: f64,
            _width: usize,
            _height: usize,
            _rgb: &mut [u8],
        ) -> Result<f64, String> {
            match self.never {}
        }

        pub fn classified_bytes(&self) -> usize {
            match self.never {}
        }
    }
}

pub use imp::VolPack;
