//! map_server's pixel semantics: how a pixel becomes a cell ([`ImageParams`], [`MapMode`],
//! `World::from_image`), with map_server's default thresholds.

use image::DynamicImage;

use crate::world::{Truth, World};

/// Cell size used for plain images when the caller gives none (m).
pub const DEFAULT_RESOLUTION_M: f64 = 0.05;
/// map_server's usual `occupied_thresh`.
pub const DEFAULT_OCCUPIED_THRESH: f64 = 0.65;
/// map_server's usual `free_thresh`.
pub const DEFAULT_FREE_THRESH: f64 = 0.196;

/// How pixel values become [`Truth`] and where the map sits (map_server parameters).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImageParams {
    /// Cell edge (m).
    pub resolution_m: f64,
    /// World position (m) of the lower-left corner of the image.
    pub origin_m: (f64, f64),
    /// Invert the brightness ↔ occupancy relation.
    pub negate: bool,
    /// Occupied if the occupancy is above this.
    pub occupied_thresh: f64,
    /// Free if the occupancy is below this.
    pub free_thresh: f64,
    /// Pixel interpretation.
    pub mode: MapMode,
}

impl Default for ImageParams {
    /// 0.05 m, origin (0, 0), thresholds 0.65 / 0.196, not negated, trinary.
    fn default() -> Self {
        ImageParams {
            resolution_m: DEFAULT_RESOLUTION_M,
            origin_m: (0.0, 0.0),
            negate: false,
            occupied_thresh: DEFAULT_OCCUPIED_THRESH,
            free_thresh: DEFAULT_FREE_THRESH,
            mode: MapMode::Trinary,
        }
    }
}

impl ImageParams {
    /// Truth of a pixel of brightness `v` in [0, 1] (1 = white).
    fn classify(&self, v: f64) -> Truth {
        let v = v.clamp(0.0, 1.0);
        let v = if self.negate { 1.0 - v } else { v };
        let p = match self.mode {
            MapMode::Trinary | MapMode::Scale => 1.0 - v,
            MapMode::Raw => {
                let raw = (v * 255.0).round();
                if raw > 100.0 {
                    return Truth::Unknown;
                }
                raw / 100.0
            }
        };
        if p > self.occupied_thresh {
            Truth::Occupied
        } else if p < self.free_thresh {
            Truth::Free
        } else {
            Truth::Unknown
        }
    }

    fn lut(&self, levels: usize) -> Vec<Truth> {
        let max = (levels - 1) as f64;
        (0..levels).map(|i| self.classify(i as f64 / max)).collect()
    }
}

/// How map_server interprets pixel values (`mode` in the YAML).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum MapMode {
    /// Three levels from the thresholds (the default).
    #[default]
    Trinary,
    /// Continuous in map_server; for ground truth it is read exactly like [`MapMode::Trinary`].
    Scale,
    /// The pixel value (after `negate`) is the occupancy in percent; values above 100 are
    /// unknown. For ground truth, `value / 100` is thresholded like the other modes.
    Raw,
}

impl World {
    /// Ground truth from a decoded image with map_server semantics (see the module docs); the
    /// top image row becomes the highest row. `params` are used as given (the loaders validate
    /// them first).
    pub fn from_image(image: &DynamicImage, params: &ImageParams) -> World {
        let (w, h) = (image.width() as usize, image.height() as usize);
        let mut cells = vec![Truth::Unknown; w * h];
        // `f(x, y_top)` classifies one pixel; rows are written bottom-up.
        let mut fill = |f: &dyn Fn(usize, usize) -> Truth| {
            for (r, row) in cells.chunks_exact_mut(w.max(1)).enumerate() {
                let y_top = h - 1 - r;
                for (x, c) in row.iter_mut().enumerate() {
                    *c = f(x, y_top);
                }
            }
        };
        let lum = |r: f64, g: f64, b: f64| 0.299 * r + 0.587 * g + 0.114 * b;
        match image {
            DynamicImage::ImageLuma8(img) => {
                let lut = params.lut(256);
                let raw = img.as_raw();
                fill(&|x, y| lut[usize::from(raw[y * w + x])]);
            }
            DynamicImage::ImageLuma16(img) => {
                let lut = params.lut(65536);
                let raw = img.as_raw();
                fill(&|x, y| lut[usize::from(raw[y * w + x])]);
            }
            DynamicImage::ImageLumaA8(img) => {
                let lut = params.lut(256);
                let raw = img.as_raw();
                fill(&|x, y| {
                    let i = 2 * (y * w + x);
                    match raw[i + 1] {
                        0 => Truth::Unknown,
                        _ => lut[usize::from(raw[i])],
                    }
                });
            }
            DynamicImage::ImageLumaA16(img) => {
                let lut = params.lut(65536);
                let raw = img.as_raw();
                fill(&|x, y| {
                    let i = 2 * (y * w + x);
                    match raw[i + 1] {
                        0 => Truth::Unknown,
                        _ => lut[usize::from(raw[i])],
                    }
                });
            }
            DynamicImage::ImageRgb8(img) => {
                let raw = img.as_raw();
                fill(&|x, y| {
                    let p = &raw[3 * (y * w + x)..][..3];
                    let l = lum(p[0].into(), p[1].into(), p[2].into());
                    params.classify(l / 255.0)
                });
            }
            DynamicImage::ImageRgba8(img) => {
                let raw = img.as_raw();
                fill(&|x, y| {
                    let p = &raw[4 * (y * w + x)..][..4];
                    if p[3] == 0 {
                        return Truth::Unknown;
                    }
                    let l = lum(p[0].into(), p[1].into(), p[2].into());
                    params.classify(l / 255.0)
                });
            }
            DynamicImage::ImageRgb16(img) => {
                let raw = img.as_raw();
                fill(&|x, y| {
                    let p = &raw[3 * (y * w + x)..][..3];
                    let l = lum(p[0].into(), p[1].into(), p[2].into());
                    params.classify(l / 65535.0)
                });
            }
            DynamicImage::ImageRgba16(img) => {
                let raw = img.as_raw();
                fill(&|x, y| {
                    let p = &raw[4 * (y * w + x)..][..4];
                    if p[3] == 0 {
                        return Truth::Unknown;
                    }
                    let l = lum(p[0].into(), p[1].into(), p[2].into());
                    params.classify(l / 65535.0)
                });
            }
            other => {
                let img = other.to_rgba32f();
                fill(&|x, y| {
                    let p = img.get_pixel(x as u32, y as u32).0;
                    if p[3] <= 0.0 {
                        return Truth::Unknown;
                    }
                    params.classify(lum(p[0].into(), p[1].into(), p[2].into()))
                });
            }
        }
        World {
            width: w,
            height: h,
            resolution_m: params.resolution_m,
            origin_m: params.origin_m,
            cells,
        }
    }
}
