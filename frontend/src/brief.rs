//! Steered BRIEF, as in ORB: why this exists is that re-identification
//! (`reid.rs`) has to recognise a landmark by its look alone, seen again
//! long after and from another heading, and a binary descriptor is cheap
//! to compute on every new feature and to compare against thousands
//! stored. 256 intensity comparisons between point pairs of a 31×31 patch
//! of a box-blurred image, the pattern turned by the patch's orientation
//! (the angle of its intensity centroid, `atan2(m₀₁, m₁₀)`), so a drone
//! that yawed between its visits still matches; compared by Hamming
//! distance.

use crate::image::{box_blur, dot, Gray};
use crate::synthetic::SplitMix;

/// A 256-bit binary descriptor.
pub type Descriptor = [u64; 4];

/// The pattern, and the blurred frame descriptors are taken from.
#[derive(Clone, Debug)]
pub struct Brief {
    /// The pattern's point pairs by coordinate (`x₀, y₀, x₁, y₁`, 256
    /// each), so turning all of them is one pass that vectorises.
    pattern: [Vec<f32>; 4],
    /// Each pair's two points as offsets in the image, once turned
    /// (scratch of [`Brief::describe`]).
    offsets: [Vec<i32>; 2],
    blurred: Gray,
    row: Vec<f32>,
}

impl Default for Brief {
    fn default() -> Self {
        Self::new()
    }
}

impl Brief {
    /// 256 point pairs, Gaussian-ish around the centre (the sum of two
    /// uniforms), inside the patch once turned; always the same pairs.
    pub fn new() -> Self {
        let mut r = SplitMix::new(0x5eed);
        let mut c = || {
            let v = ((r.unit() + r.unit() - 1.0) * 11.0).round() as i8;
            v.clamp(-11, 11)
        };
        let mut pattern: [Vec<f32>; 4] = Default::default();
        for _ in 0..256 {
            for p in pattern.iter_mut() {
                p.push(f32::from(c()));
            }
        }
        Self {
            pattern,
            offsets: [vec![0; 256], vec![0; 256]],
            blurred: Gray::default(),
            row: Vec::new(),
        }
    }

    /// Takes the frame to describe features in: its 5×5 box blur.
    pub fn set_image(&mut self, img: &Gray) {
        box_blur(img, &mut self.blurred, &mut self.row);
    }

    /// The blurred frame of [`Brief::set_image`].
    pub fn blurred(&self) -> &Gray {
        &self.blurred
    }

    /// The steered-BRIEF descriptor at `(u, v)`, if its patch fits.
    pub fn describe(&mut self, u: f32, v: f32) -> Option<Descriptor> {
        let img = &self.blurred;
        // Rounded to the nearest pixel by adding a half and truncating
        // (a position outside the image is refused below either way).
        let (cx, cy) = ((u + 0.5) as i32, (v + 0.5) as i32);
        if cx < HALF + 1 || cy < HALF + 1 || cx >= img.width as i32 - HALF - 1 || cy >= img.height as i32 - HALF - 1 {
            return None;
        }
        // The intensity centroid's angle over the disc of radius HALF, a
        // row's run of pixels at a time (`DISC_HALF_WIDTH`): Σ dx·p along
        // the row, and dy times the row's sum.
        let (mut m10, mut m01) = (0.0f32, 0.0f32);
        for dy in -HALF..=HALF {
            let hw = DISC_HALF_WIDTH[(dy + HALF) as usize];
            let at = (cy + dy) as usize * img.width + cx as usize;
            let row = &img.px[at - hw as usize..=at + hw as usize];
            let xs = &DX[(HALF - hw) as usize..=(HALF + hw) as usize];
            m10 += dot(row, xs);
            m01 += dy as f32 * dot(row, &ONES[..row.len()]);
        }
        let (s, c) = m01.atan2(m10).sin_cos();
        // Each pair's points turned by the angle, rounded to the nearest
        // pixel (the turned offsets lie within ±16, so shifted by 32.5
        // they are positive and truncation is the rounding, without a
        // call to `roundf`), as offsets in the image.
        let w = img.width as i32;
        let round = |v: f32| (v + 32.5) as i32 - 32;
        let [x0, y0, x1, y1] = &self.pattern;
        let [o0, o1] = &mut self.offsets;
        for (o, (x, y)) in [(&mut *o0, (x0, y0)), (&mut *o1, (x1, y1))] {
            for ((o, &x), &y) in o.iter_mut().zip(x.iter()).zip(y.iter()) {
                *o = round(s * x + c * y) * w + round(c * x - s * y);
            }
        }
        let centre = cy * w + cx;
        let mut d = [0u64; 4];
        for (word, (a, b)) in d.iter_mut().zip(o0.chunks_exact(64).zip(o1.chunks_exact(64))) {
            for (bit, (&a, &b)) in a.iter().zip(b).enumerate() {
                let (pa, pb) = (img.px[(centre + a) as usize], img.px[(centre + b) as usize]);
                *word |= u64::from(pa < pb) << bit;
            }
        }
        Some(d)
    }
}

/// The bits in which two descriptors differ.
pub fn hamming(a: &Descriptor, b: &Descriptor) -> u32 {
    (0..4).map(|w| (a[w] ^ b[w]).count_ones()).sum()
}

/// The index of `d`'s match in `set`: the nearest within `max_distance`
/// bits (of 256), clearly nearer than the second (its distance below
/// `ratio` times the second's: the ratio test).
pub fn best_match<'a>(
    d: &Descriptor,
    set: impl Iterator<Item = (usize, &'a Descriptor)>,
    max_distance: u32,
    ratio: f32,
) -> Option<usize> {
    let (mut b1, mut b2, mut k1) = (u32::MAX, u32::MAX, 0);
    for (k, e) in set {
        let dist = hamming(d, e);
        if dist < b1 {
            b2 = b1;
            b1 = dist;
            k1 = k;
        } else if dist < b2 {
            b2 = dist;
        }
    }
    (b1 <= max_distance && (b1 as f32) < ratio * b2 as f32).then_some(k1)
}

/// The patch's half side (px).
const HALF: i32 = 15;

/// A row's pixel offsets from the patch centre, `-HALF..=HALF`, and as
/// many ones: the weights of the centroid's two sums.
const DX: [f32; 2 * HALF as usize + 1] = {
    let mut d = [0.0f32; 2 * HALF as usize + 1];
    let mut i = 0;
    while i < d.len() {
        d[i] = i as f32 - HALF as f32;
        i += 1;
    }
    d
};
const ONES: [f32; 2 * HALF as usize + 1] = [1.0; 2 * HALF as usize + 1];

/// The disc of radius `HALF`: each row's half width, `dy` from `-HALF`.
const DISC_HALF_WIDTH: [i32; 2 * HALF as usize + 1] = {
    let mut w = [0i32; 2 * HALF as usize + 1];
    let mut i = 0;
    while i < w.len() {
        let dy = i as i32 - HALF;
        let mut hw = 0;
        while (hw + 1) * (hw + 1) + dy * dy <= HALF * HALF {
            hw += 1;
        }
        w[i] = hw;
        i += 1;
    }
    w
};

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_disc_rows_hold_exactly_the_disc() {
        for dy in -HALF..=HALF {
            let n = (-HALF..=HALF).filter(|dx| dx * dx + dy * dy <= HALF * HALF).count() as i32;
            assert_eq!(n, 2 * DISC_HALF_WIDTH[(dy + HALF) as usize] + 1, "dy {dy}");
        }
    }

    /// A patch turned by a quarter turn gives the same descriptor (up to
    /// the pixels the rounding of the turned pattern moves), and another
    /// patch a distant one: the steering at work.
    #[test]
    fn a_turned_patch_keeps_its_descriptor() {
        let img = crate::synthetic::textured(200, 200, 9, 0.0, 0.0);
        // The same image turned by 90° about (100, 100).
        let mut turned = Gray::new(200, 200);
        for y in 0..200 {
            for x in 0..200 {
                turned.px[y * 200 + x] = img.px[(199 - x) * 200 + y];
            }
        }
        let mut b = Brief::new();
        b.set_image(&img);
        let (d, other) = (b.describe(100.0, 100.0).unwrap(), b.describe(60.0, 140.0).unwrap());
        b.set_image(&turned);
        let dt = b.describe(99.0, 100.0).unwrap();
        assert!(hamming(&d, &dt) < 50, "turned: {}", hamming(&d, &dt));
        assert!(hamming(&d, &other) > 80, "another patch: {}", hamming(&d, &other));
        assert_eq!(best_match(&dt, [d, other].iter().enumerate(), 50, 0.8), Some(0));
    }
}
