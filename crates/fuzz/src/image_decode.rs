//! Encoded images (PNG, JPEG, PNM, TIFF, BMP) as uploads carry them, decoded within small
//! limits; a small decoded image then goes through segment extraction.

use trinocular::extract;

/// Largest decoded image (pixels) that extraction is run on: keeps one execution short.
const EXTRACT_MAX_PIXELS: u32 = 128 * 128;

pub fn run(data: &[u8]) {
    let limits = crate::decode_limits();
    let decoded = extract::decode(data, &limits);
    crate::debug(|| {
        let size = decoded.as_ref().map(|i| (i.width(), i.height()));
        format!("decode: {size:?}")
    });
    if let Ok(image) = decoded {
        assert!(image.width() >= 1 && image.height() >= 1);
        assert_eq!(
            image.pixels().len() as u64,
            u64::from(image.width()) * u64::from(image.height())
        );
        assert!(u64::from(image.width()) * u64::from(image.height()) <= limits.max_pixels);
        if image.width().saturating_mul(image.height()) <= EXTRACT_MAX_PIXELS {
            let found = extract::extract(&image, None, &extract::Params::default());
            crate::debug(|| format!("extract: {} segments", found.segments.segments.len()));
        }
    }
    // Raw grey pixels, the other way images come: width and height from the first bytes.
    if let [w, h, rest @ ..] = data {
        let _ = extract::from_raw(u32::from(*w), u32::from(*h), rest, &limits);
    }
}
