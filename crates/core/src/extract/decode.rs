//! Decoding of uploaded images into a [`GreyImage`]: PNG, JPEG, PGM/PPM, TIFF and BMP files,
//! the format told by the content (never by a name or a MIME type), or raw 8-bit grey buffers
//! for clients that would rather not encode.
//!
//! Why: the service accepts images from untrusted clients, so decoding must refuse cheaply
//! what it cannot or will not handle, before spending memory on it. The limits are checked in
//! the order that costs least: the upload's length first, then the width and height read
//! from the file's header, and only then are the pixels decoded. A decompression bomb (a
//! small file whose header claims a huge image) is thus refused without allocating its
//! pixels. The `image` crate's own allocation limit ([`image::Limits::max_alloc`]) is set
//! too, as a second line of defence for buffers this module cannot see (metadata chunks,
//! TIFF strips).
//!
//! Grey levels: every source depth lands on the 8-bit scale 0–255 as `f32`, keeping the
//! fraction: 8-bit values as they are, 16-bit values divided by 257 (65535 → 255.0,
//! 257 → 1.0), 32-bit float values multiplied by 255 (1.0 → 255.0, clamped to 0–255, NaN →
//! 0). Colour becomes luma with the Rec. 709 (sRGB) weights the `image` crate itself uses,
//! `Y = 0.2126 R + 0.7152 G + 0.0722 B`, applied to the stored (gamma-encoded) values as the
//! `image` crate does, but without its rounding to an integer. Alpha is ignored. ICC
//! profiles and EXIF orientation are ignored too: pixels stay in the order the sensor stored
//! them, which is the order the camera calibration refers to.
//!
//! Failures are [`DecodeError`] values, each carrying the offending numbers and worded for an
//! API user. This module's own code has no panicking path on input; the decoders are the
//! `image` crate's, so a property test feeds them arbitrary bytes and mutated valid files.
//! A JPEG that stops before its end marker is refused here, as the crate's lenient JPEG
//! decoder would fill the missing part with grey (see `jpeg_reaches_end`).

use std::error::Error as _;
use std::io::Cursor;

use image::{DynamicImage, ImageDecoder, ImageError, ImageFormat, ImageReader};

use super::image::GreyImage;

/// The formats the service accepts, as a user reads them.
const ACCEPTED: &str = "PNG, JPEG, PGM/PPM, TIFF or BMP";

/// Bytes per pixel of the decoded buffer allowed at the pixel limit: 8-bit RGB. A wider
/// pixel (16-bit, alpha, float) is accepted on a smaller image, so that a small file cannot
/// make the decoder allocate `max_pixels` × 16 bytes (a 280 KB 16-bit RGBA PNG of 6000 x 6000
/// would take 288 MB decoded).
const DECODED_BYTES_PER_PIXEL: u64 = 3;

/// Bounds on what [`decode`] and [`from_raw`] accept.
///
/// The defaults fit most industrial and consumer cameras while bounding the memory one
/// command can take: 12 megapixels (4000 × 3000) decodes to at most 48 MB of `f32` grey,
/// plus, transiently, the decoded file (36 MB for 8-bit RGB), and extracting segments from
/// three such images needs up to about 1.3 GB (36 bytes a pixel on the worst content). The
/// service, many requests on one machine, sets its own lower limit. 32 MiB of encoded
/// data holds such an image as a JPEG or PNG, or uncompressed (PGM, BMP) as 8-bit grey;
/// beyond that a client can send raw pixels ([`from_raw`]), to which the byte limit does not
/// apply.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DecodeLimits {
    /// Largest encoded upload accepted, in bytes (checked before anything else).
    pub max_bytes: usize,
    /// Largest `width × height` accepted (checked on the header, before decoding pixels).
    pub max_pixels: u64,
}

impl Default for DecodeLimits {
    fn default() -> Self {
        DecodeLimits {
            max_bytes: 32 * 1024 * 1024,
            max_pixels: 12_000_000,
        }
    }
}

/// Why an image was refused. Messages are meant for API users and read well after a field
/// name, as in `images[1].encoded: the image is 0 bytes long`.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DecodeError {
    #[error("the image is 0 bytes long")]
    Empty,
    #[error("the image is {bytes} bytes long, more than the {max} bytes allowed")]
    TooManyBytes { bytes: usize, max: usize },
    #[error("the image is {width} x {height} pixels, more than the {max} pixels allowed")]
    TooManyPixels { width: u32, height: u32, max: u64 },
    #[error("the image is {width} x {height} pixels; width and height must both be at least 1")]
    ZeroSize { width: u32, height: u32 },
    #[error(
        "the image is {width} x {height} pixels of {bytes_per_pixel} bytes each: decoded it \
         would take {bytes} bytes, more than the {max} allowed (8-bit RGB at the pixel limit); \
         send 8-bit samples"
    )]
    TooWideDecoded {
        width: u32,
        height: u32,
        bytes_per_pixel: u64,
        bytes: u64,
        max: u64,
    },
    #[error("unsupported image: {what}")]
    Unsupported { what: String },
    #[error("the {format} data is corrupt or truncated: {message}")]
    Corrupt { format: String, message: String },
    #[error(
        "raw grey data for {width} x {height} pixels must be {expected} bytes \
         (one byte per pixel, row by row), got {got}"
    )]
    RawSize {
        width: u32,
        height: u32,
        expected: u64,
        got: u64,
    },
    #[error(
        "the image is {width} x {height} pixels but the camera's calibration is for \
         {expected_width} x {expected_height}"
    )]
    SizeMismatch {
        width: u32,
        height: u32,
        expected_width: u32,
        expected_height: u32,
    },
}

/// Decodes an encoded image (PNG, JPEG, PGM/PPM, TIFF or BMP, told by its content) into grey
/// levels on the 8-bit scale; see the module doc for depths, colour and alpha.
pub fn decode(bytes: &[u8], limits: &DecodeLimits) -> Result<GreyImage, DecodeError> {
    decode_sized(bytes, limits, None)
}

/// [`decode`], refusing from the header, before any pixel is decoded, an image whose size
/// is not `expected` (width, height): its camera's.
pub fn decode_sized(
    bytes: &[u8],
    limits: &DecodeLimits,
    expected: Option<(u32, u32)>,
) -> Result<GreyImage, DecodeError> {
    if bytes.is_empty() {
        return Err(DecodeError::Empty);
    }
    if bytes.len() > limits.max_bytes {
        return Err(DecodeError::TooManyBytes {
            bytes: bytes.len(),
            max: limits.max_bytes,
        });
    }

    // Reading from memory cannot fail, but the signature says io::Result: treat it as corrupt
    // rather than unwrap.
    let mut reader = ImageReader::new(Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| DecodeError::Corrupt {
            format: "image".into(),
            message: e.to_string(),
        })?;
    let format = match reader.format() {
        None => {
            return Err(DecodeError::Unsupported {
                what: format!("the format was not recognised (send {ACCEPTED})"),
            })
        }
        Some(format) => format,
    };
    let name = match format_name(format) {
        Some(name) => name,
        // Formats the crate recognises but this service does not decode (GIF, WebP, ...).
        None => {
            let known = format
                .extensions_str()
                .first()
                .map_or_else(|| format!("{format:?}"), |ext| ext.to_uppercase());
            return Err(DecodeError::Unsupported {
                what: format!("{known} images are not accepted (send {ACCEPTED})"),
            });
        }
    };

    reader.limits(image_limits(limits));
    // `into_decoder` reads only the header (and, for PNG, the chunks before the pixel data):
    // no pixel buffer exists yet.
    let decoder = reader.into_decoder().map_err(|e| image_error(name, e))?;
    let (width, height) = decoder.dimensions();
    check_pixels(width, height, limits)?;
    if let Some((expected_width, expected_height)) = expected {
        if (width, height) != (expected_width, expected_height) {
            return Err(DecodeError::SizeMismatch {
                width,
                height,
                expected_width,
                expected_height,
            });
        }
    }
    let decoded_bytes = decoder.total_bytes();
    if decoded_bytes > decoded_budget(limits) {
        return Err(DecodeError::TooWideDecoded {
            width,
            height,
            bytes_per_pixel: decoded_bytes / (u64::from(width) * u64::from(height)),
            bytes: decoded_bytes,
            max: decoded_budget(limits),
        });
    }
    if format == ImageFormat::Jpeg {
        jpeg_reaches_end(bytes).map_err(|message| DecodeError::Corrupt {
            format: name.into(),
            message,
        })?;
    }
    let decoded = DynamicImage::from_decoder(decoder).map_err(|e| image_error(name, e))?;
    to_grey(&decoded)
}

/// An encoded image's width and height from its header alone (no pixel decoded), or `None`
/// when the header cannot be read (decoding will then say why).
pub fn dimensions(bytes: &[u8], limits: &DecodeLimits) -> Option<(u32, u32)> {
    let mut reader = ImageReader::new(Cursor::new(bytes))
        .with_guessed_format()
        .ok()?;
    format_name(reader.format()?)?;
    reader.limits(image_limits(limits));
    reader.into_dimensions().ok()
}

/// Wraps a raw 8-bit grey buffer, row by row, one byte per pixel, `width × height` bytes.
///
/// `limits.max_bytes` does not apply: the size is fully determined by the pixel count, which
/// `limits.max_pixels` bounds.
pub fn from_raw(
    width: u32,
    height: u32,
    data: &[u8],
    limits: &DecodeLimits,
) -> Result<GreyImage, DecodeError> {
    check_pixels(width, height, limits)?;
    let expected = u64::from(width) * u64::from(height);
    let got = data.len() as u64;
    if got != expected {
        return Err(DecodeError::RawSize {
            width,
            height,
            expected,
            got,
        });
    }
    GreyImage::from_u8(width, height, data).ok_or(DecodeError::RawSize {
        width,
        height,
        expected,
        got,
    })
}

/// Refuses an image whose size differs from the one its camera was calibrated at: the
/// calibration's intrinsics are in pixels of that size, so a resized or cropped image
/// would be reconstructed wrongly rather than fail.
pub fn check_size(
    image: &GreyImage,
    expected_width: u32,
    expected_height: u32,
) -> Result<(), DecodeError> {
    if image.width() == expected_width && image.height() == expected_height {
        Ok(())
    } else {
        Err(DecodeError::SizeMismatch {
            width: image.width(),
            height: image.height(),
            expected_width,
            expected_height,
        })
    }
}

/// Zero sides first (a 0 × N image is no image), then the pixel count.
fn check_pixels(width: u32, height: u32, limits: &DecodeLimits) -> Result<(), DecodeError> {
    if width == 0 || height == 0 {
        return Err(DecodeError::ZeroSize { width, height });
    }
    if u64::from(width) * u64::from(height) > limits.max_pixels {
        return Err(DecodeError::TooManyPixels {
            width,
            height,
            max: limits.max_pixels,
        });
    }
    Ok(())
}

/// The most a decoder may allocate: the decoded buffer of the largest accepted image in the
/// widest layout, plus intermediate buffers (compressed strips, metadata) no larger than the
/// upload itself.
fn alloc_budget(limits: &DecodeLimits) -> u64 {
    decoded_budget(limits).saturating_add(limits.max_bytes as u64)
}

/// The largest decoded pixel buffer accepted, bytes.
fn decoded_budget(limits: &DecodeLimits) -> u64 {
    limits.max_pixels.saturating_mul(DECODED_BYTES_PER_PIXEL)
}

/// The `image` crate's limits. Width and height are left unbounded on purpose: the product
/// is what matters, and checking it in [`decode`] gives an error that names both.
fn image_limits(limits: &DecodeLimits) -> image::Limits {
    let mut l = image::Limits::no_limits();
    l.max_alloc = Some(alloc_budget(limits));
    l
}

/// The formats decoded here, by the name a user knows them by.
fn format_name(format: ImageFormat) -> Option<&'static str> {
    match format {
        ImageFormat::Png => Some("PNG"),
        ImageFormat::Jpeg => Some("JPEG"),
        ImageFormat::Pnm => Some("PGM/PPM"),
        ImageFormat::Tiff => Some("TIFF"),
        ImageFormat::Bmp => Some("BMP"),
        _ => None,
    }
}

/// Maps the `image` crate's error, once the format is known. Its `Display` prefixes
/// "Format error decoding Png: "; the underlying decoder's message alone reads better after
/// our own prefix.
fn image_error(format: &str, err: ImageError) -> DecodeError {
    let message = err
        .source()
        .map_or_else(|| err.to_string(), |source| source.to_string())
        .trim()
        .to_string();
    match err {
        ImageError::Unsupported(e) => DecodeError::Unsupported {
            what: format!("{format}: {e}"),
        },
        // Reading from memory, an I/O error is the decoder running off the end of the data.
        ImageError::IoError(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => {
            DecodeError::Corrupt {
                format: format.into(),
                message: "the data ends early (truncated file?)".into(),
            }
        }
        // The pixel count was checked before: a decoder that wants more memory than the
        // budget was asked for it by a malformed file (huge metadata, absurd strip sizes).
        ImageError::Limits(_) => DecodeError::Corrupt {
            format: format.into(),
            message: "decoding it would need more memory than its size justifies".into(),
        },
        _ => DecodeError::Corrupt {
            format: format.into(),
            message,
        },
    }
}

/// Checks that a JPEG's marker structure reaches its end-of-image marker.
///
/// Why: the `image` crate runs its JPEG decoder (zune-jpeg) in lenient mode, which decodes a
/// file cut inside its compressed data without complaint, filling the missing blocks with
/// mid grey. A truncated upload would then give edges that are not in the scene. Only the
/// marker structure is walked: segments are skipped by their length (so an EXIF thumbnail's
/// own end marker is never mistaken for ours), compressed data is scanned for the next
/// marker. Stray bytes between segments are skipped, as libjpeg does; data after the end
/// marker (phones append videos there) is ignored.
fn jpeg_reaches_end(data: &[u8]) -> Result<(), String> {
    const TRUNCATED: &str = "the data ends before the JPEG end-of-image marker (truncated file?)";
    // After the start-of-image marker, FF D8.
    let mut i = 2;
    loop {
        // Find the next marker: FF followed by neither FF (fill) nor 00.
        while i + 1 < data.len() && !(data[i] == 0xFF && data[i + 1] != 0xFF && data[i + 1] != 0) {
            i += 1;
        }
        let Some(&marker) = data.get(i + 1) else {
            return Err(TRUNCATED.into());
        };
        i += 2;
        match marker {
            0xD9 => return Ok(()),
            // Markers without a length: restart markers (inside compressed data), TEM, SOI.
            0xD0..=0xD8 | 0x01 => {}
            _ => {
                let (Some(&hi), Some(&lo)) = (data.get(i), data.get(i + 1)) else {
                    return Err(TRUNCATED.into());
                };
                let len = usize::from(u16::from_be_bytes([hi, lo]));
                if len < 2 {
                    return Err(format!("invalid JPEG segment length {len}"));
                }
                // A frame header (SOF0..SOF15 but DHT C4, JPG C8, DAC CC).
                if matches!(marker, 0xC0..=0xCF) && !matches!(marker, 0xC4 | 0xC8 | 0xCC) {
                    jpeg_sampling_supported(data.get(i + 2..i + len).unwrap_or(&[]))?;
                }
                // The scan's compressed data follows its header; the loop above then skips
                // it, as stuffed FF 00 and restart markers are not segment markers.
                i += len;
                if i > data.len() {
                    return Err(TRUNCATED.into());
                }
            }
        }
    }
}

/// Refuses a frame whose colour components sample more finely than its first (luma)
/// component in either direction. Encoders never write such files (chroma is subsampled, not
/// supersampled), and the JPEG decoder the `image` crate uses (zune-jpeg 0.5.15) panics on
/// some of them in its upsampler (found by `fuzz/fuzz_targets/image_decode.rs`; the input is
/// in its corpus). `frame`: the SOF segment after its length: precision, height, width,
/// component count, then 3 bytes per component (id, sampling h<<4|v, table).
fn jpeg_sampling_supported(frame: &[u8]) -> Result<(), String> {
    let Some(&count) = frame.get(5) else {
        return Ok(()); // a short header: the decoder says what is wrong
    };
    let sampling: Vec<(u8, u8)> = frame[6..]
        .chunks_exact(3)
        .take(usize::from(count))
        .map(|c| (c[1] >> 4, c[1] & 0x0F))
        .collect();
    let Some(&(h0, v0)) = sampling.first() else {
        return Ok(());
    };
    match sampling.iter().position(|&(h, v)| h > h0 || v > v0) {
        Some(k) => Err(format!(
            "unsupported JPEG sampling: component {} samples {}x{}, more finely than the \
             first component's {h0}x{v0}",
            k + 1,
            sampling[k].0,
            sampling[k].1
        )),
        None => Ok(()),
    }
}

/// Rec. 709 luma on whatever scale the channels are in. Integer weights (those of the
/// `image` crate) in `f64` keep sums exact, so that white stays exactly white.
#[inline]
fn luma(r: f64, g: f64, b: f64) -> f64 {
    (2126.0 * r + 7152.0 * g + 722.0 * b) / 10_000.0
}

/// Grey levels from interleaved samples: the first channel for grey (± alpha), luma of the
/// first three for colour (± alpha). `scale` maps a sample to the 8-bit scale.
fn grey_from<T: Copy + Into<f64>>(samples: &[T], channels: usize, scale: f64) -> Vec<f32> {
    let level = |v: f64| -> f32 {
        let v = v * scale;
        // Float images may hold NaN or values outside 0–1; integer ones never do.
        if v.is_nan() {
            0.0
        } else {
            v.clamp(0.0, 255.0) as f32
        }
    };
    if channels >= 3 {
        samples
            .chunks_exact(channels)
            .map(|p| level(luma(p[0].into(), p[1].into(), p[2].into())))
            .collect()
    } else {
        samples
            .chunks_exact(channels.max(1))
            .map(|p| level(p[0].into()))
            .collect()
    }
}

fn to_grey(img: &DynamicImage) -> Result<GreyImage, DecodeError> {
    const U16: f64 = 1.0 / 257.0;
    let pixels = match img {
        DynamicImage::ImageLuma8(b) => b.as_raw().iter().map(|&v| f32::from(v)).collect(),
        DynamicImage::ImageLumaA8(b) => grey_from(b.as_raw(), 2, 1.0),
        DynamicImage::ImageRgb8(b) => grey_from(b.as_raw(), 3, 1.0),
        DynamicImage::ImageRgba8(b) => grey_from(b.as_raw(), 4, 1.0),
        DynamicImage::ImageLuma16(b) => grey_from(b.as_raw(), 1, U16),
        DynamicImage::ImageLumaA16(b) => grey_from(b.as_raw(), 2, U16),
        DynamicImage::ImageRgb16(b) => grey_from(b.as_raw(), 3, U16),
        DynamicImage::ImageRgba16(b) => grey_from(b.as_raw(), 4, U16),
        DynamicImage::ImageRgb32F(b) => grey_from(b.as_raw(), 3, 255.0),
        DynamicImage::ImageRgba32F(b) => grey_from(b.as_raw(), 4, 255.0),
        // The enum is non-exhaustive: a layout added later goes through the crate's own
        // conversion (same weights, float output on the 0–1 scale).
        other => grey_from(other.to_luma32f().as_raw(), 1, 255.0),
    };
    let (width, height) = (img.width(), img.height());
    GreyImage::new(width, height, pixels).ok_or_else(|| DecodeError::Corrupt {
        format: "image".into(),
        message: format!("the decoder returned the wrong number of pixels for {width} x {height}"),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::codecs::jpeg::JpegEncoder;
    use image::codecs::pnm::{PnmEncoder, PnmSubtype, SampleEncoding};
    use image::{ImageBuffer, Luma, Rgb, Rgb32FImage, Rgba};
    use proptest::prelude::*;

    fn encode(img: &DynamicImage, format: ImageFormat) -> Vec<u8> {
        let mut out = Cursor::new(Vec::new());
        img.write_to(&mut out, format).unwrap();
        out.into_inner()
    }

    /// Binary PGM for grey, PPM for colour (the crate's default PNM header is PAM, `P7`).
    fn pnm(img: &DynamicImage) -> Vec<u8> {
        let subtype = match img.color() {
            image::ColorType::L8 => PnmSubtype::Graymap(SampleEncoding::Binary),
            _ => PnmSubtype::Pixmap(SampleEncoding::Binary),
        };
        let mut out = Vec::new();
        img.write_with_encoder(PnmEncoder::new(&mut out).with_subtype(subtype))
            .unwrap();
        out
    }

    /// A 7 × 5 grey ramp (odd sizes catch row padding bugs in BMP and friends).
    fn ramp8() -> ImageBuffer<Luma<u8>, Vec<u8>> {
        ImageBuffer::from_fn(7, 5, |x, y| Luma([(x * 30 + y * 7) as u8]))
    }

    fn rgb8() -> ImageBuffer<Rgb<u8>, Vec<u8>> {
        ImageBuffer::from_fn(7, 5, |x, y| {
            Rgb([(x * 30) as u8, (y * 50) as u8, (x * 10 + y * 20) as u8])
        })
    }

    fn luma8(p: Rgb<u8>) -> f32 {
        luma(f64::from(p[0]), f64::from(p[1]), f64::from(p[2])) as f32
    }

    fn assert_grey_ramp(g: &GreyImage) {
        let ramp = ramp8();
        assert_eq!((g.width(), g.height()), (7, 5));
        for (x, y, p) in ramp.enumerate_pixels() {
            assert_eq!(g.at(x as usize, y as usize), f32::from(p[0]), "at {x},{y}");
        }
    }

    fn assert_rgb(g: &GreyImage) {
        let rgb = rgb8();
        assert_eq!((g.width(), g.height()), (7, 5));
        for (x, y, p) in rgb.enumerate_pixels() {
            assert!(
                (g.at(x as usize, y as usize) - luma8(*p)).abs() < 1e-4,
                "at {x},{y}"
            );
        }
    }

    fn ok(bytes: &[u8]) -> GreyImage {
        decode(bytes, &DecodeLimits::default()).unwrap()
    }

    fn err(bytes: &[u8]) -> DecodeError {
        decode(bytes, &DecodeLimits::default()).unwrap_err()
    }

    #[test]
    fn luma_weights_are_rec709() {
        // (200, 100, 50): 0.2126·200 + 0.7152·100 + 0.0722·50 = 117.65
        assert!((luma8(Rgb([200, 100, 50])) - 117.65).abs() < 1e-4);
        assert_eq!(luma8(Rgb([255, 255, 255])), 255.0);
    }

    #[test]
    fn png_grey_8bit() {
        assert_grey_ramp(&ok(&encode(
            &DynamicImage::ImageLuma8(ramp8()),
            ImageFormat::Png,
        )));
    }

    #[test]
    fn png_grey_16bit_keeps_the_fraction() {
        let img = ImageBuffer::<Luma<u16>, _>::from_raw(4, 1, vec![0, 257, 32768, 65535]).unwrap();
        let g = ok(&encode(&DynamicImage::ImageLuma16(img), ImageFormat::Png));
        assert_eq!(g.pixels(), &[0.0, 1.0, 32768.0 / 257.0, 255.0]);
    }

    #[test]
    fn png_rgb_and_rgba_become_luma_alpha_ignored() {
        assert_rgb(&ok(&encode(
            &DynamicImage::ImageRgb8(rgb8()),
            ImageFormat::Png,
        )));
        let rgba = ImageBuffer::from_fn(7, 5, |x, y| {
            let p = rgb8().get_pixel(x, y).0;
            Rgba([p[0], p[1], p[2], (x * 40) as u8])
        });
        assert_rgb(&ok(&encode(
            &DynamicImage::ImageRgba8(rgba),
            ImageFormat::Png,
        )));
    }

    #[test]
    fn png_rgb_16bit() {
        let img = ImageBuffer::from_raw(2, 1, vec![65535u16, 65535, 65535, 257, 0, 0]).unwrap();
        let g = ok(&encode(&DynamicImage::ImageRgb16(img), ImageFormat::Png));
        assert_eq!(g.pixels()[0], 255.0);
        assert!((g.pixels()[1] - 0.2126).abs() < 1e-6);
    }

    #[test]
    fn jpeg_within_a_few_levels() {
        // A smooth image: JPEG's error there is small at high quality.
        let smooth = ImageBuffer::from_fn(16, 16, |x, y| Luma([(60 + x * 4 + y * 3) as u8]));
        let mut bytes = Vec::new();
        JpegEncoder::new_with_quality(&mut bytes, 95)
            .encode_image(&smooth)
            .unwrap();
        let g = ok(&bytes);
        assert_eq!((g.width(), g.height()), (16, 16));
        for (x, y, p) in smooth.enumerate_pixels() {
            let d = (g.at(x as usize, y as usize) - f32::from(p[0])).abs();
            assert!(d <= 3.0, "at {x},{y}: off by {d}");
        }
        // Colour JPEG too (decoded to RGB, then luma).
        let colour = DynamicImage::ImageRgb8(ImageBuffer::from_pixel(16, 16, Rgb([200, 100, 50])));
        let g = ok(&encode(&colour, ImageFormat::Jpeg));
        assert!(g.pixels().iter().all(|&v| (v - 117.65).abs() <= 4.0));
    }

    #[test]
    fn pgm_and_ppm() {
        let pgm = pnm(&DynamicImage::ImageLuma8(ramp8()));
        assert!(pgm.starts_with(b"P5"));
        assert_grey_ramp(&ok(&pgm));
        let ppm = pnm(&DynamicImage::ImageRgb8(rgb8()));
        assert!(ppm.starts_with(b"P6"));
        assert_rgb(&ok(&ppm));
        // Hand-written ASCII PGM with a 16-bit maxval.
        let g = ok(b"P2\n3 1\n65535\n0 257 65535\n");
        assert_eq!(g.pixels(), &[0.0, 1.0, 255.0]);
    }

    #[test]
    fn tiff_grey_rgb_and_float() {
        assert_grey_ramp(&ok(&encode(
            &DynamicImage::ImageLuma8(ramp8()),
            ImageFormat::Tiff,
        )));
        assert_rgb(&ok(&encode(
            &DynamicImage::ImageRgb8(rgb8()),
            ImageFormat::Tiff,
        )));
        let img = ImageBuffer::<Luma<u16>, _>::from_raw(2, 1, vec![257, 65535]).unwrap();
        let g = ok(&encode(&DynamicImage::ImageLuma16(img), ImageFormat::Tiff));
        assert_eq!(g.pixels(), &[1.0, 255.0]);
        let float: Rgb32FImage =
            ImageBuffer::from_raw(3, 1, vec![1.0, 1.0, 1.0, 0.5, 0.5, 0.5, 2.0, -1.0, 0.0])
                .unwrap();
        let g = ok(&encode(
            &DynamicImage::ImageRgb32F(float),
            ImageFormat::Tiff,
        ));
        assert_eq!(g.pixels()[0], 255.0);
        assert!((g.pixels()[1] - 127.5).abs() < 1e-4);
        // Out of range: 2.0·0.2126 − 0.7152 < 0, clamped.
        assert_eq!(g.pixels()[2], 0.0);
    }

    #[test]
    fn bmp_grey_and_rgb() {
        assert_grey_ramp(&ok(&encode(
            &DynamicImage::ImageLuma8(ramp8()),
            ImageFormat::Bmp,
        )));
        assert_rgb(&ok(&encode(
            &DynamicImage::ImageRgb8(rgb8()),
            ImageFormat::Bmp,
        )));
    }

    #[test]
    fn truncated_files_are_corrupt() {
        let big = ImageBuffer::from_fn(64, 48, |x, y| Rgb([(x * 3 + y * 2) as u8, 7, 9]));
        let grey = DynamicImage::ImageLuma8(DynamicImage::ImageRgb8(big.clone()).to_luma8());
        let rgb = DynamicImage::ImageRgb8(big);
        for (name, bytes) in [
            ("PNG", encode(&rgb, ImageFormat::Png)),
            ("JPEG", encode(&grey, ImageFormat::Jpeg)),
            ("JPEG", encode(&rgb, ImageFormat::Jpeg)),
            ("PGM/PPM", pnm(&grey)),
            ("TIFF", encode(&rgb, ImageFormat::Tiff)),
            ("BMP", encode(&rgb, ImageFormat::Bmp)),
        ] {
            assert!(decode(&bytes, &DecodeLimits::default()).is_ok());
            for frac in [0.5, 0.9, 0.99] {
                let cut = (bytes.len() as f64 * frac) as usize;
                let e = err(&bytes[..cut]);
                assert!(
                    matches!(&e, DecodeError::Corrupt { format, .. } if format == name),
                    "{name} cut at {cut} of {}: {e:?}",
                    bytes.len()
                );
            }
        }
    }

    #[test]
    fn jpeg_end_marker_is_found_by_walking_segments() {
        let img = ImageBuffer::from_fn(32, 32, |x, y| Luma([(x * 5 + y * 3) as u8]));
        let jpeg = encode(&DynamicImage::ImageLuma8(img), ImageFormat::Jpeg);
        // Data after the end marker (as phones append) is ignored.
        let mut trailing = jpeg.clone();
        trailing.extend_from_slice(b"\0\0ftypmp42 and more");
        assert!(decode(&trailing, &DecodeLimits::default()).is_ok());
        // An APP1 segment holding FF D9 (as an EXIF thumbnail does) is skipped by its
        // length, so a file cut after it is still found truncated.
        let mut with_app = vec![0xFF, 0xD8, 0xFF, 0xE1, 0x00, 0x06, 0xFF, 0xD9, 0xFF, 0xD9];
        with_app.extend_from_slice(&jpeg[2..]);
        assert!(decode(&with_app, &DecodeLimits::default()).is_ok());
        let cut = with_app.len() - 20;
        assert!(matches!(err(&with_app[..cut]), DecodeError::Corrupt { .. }));
        assert_eq!(jpeg_reaches_end(&[0xFF, 0xD8, 0xFF, 0xD9]), Ok(()));
        assert!(jpeg_reaches_end(&[0xFF, 0xD8, 0xFF, 0xE0, 0x00, 0x01]).is_err());
        assert!(jpeg_reaches_end(&[0xFF, 0xD8, 0xFF, 0xE0, 0x00, 0x10, 0]).is_err());
    }

    #[test]
    fn unknown_and_unaccepted_formats_are_unsupported() {
        let random: Vec<u8> = (0u32..200)
            .map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8)
            .collect();
        assert!(matches!(err(&random), DecodeError::Unsupported { .. }));
        let gif = b"GIF89a\x01\x00\x01\x00\x00\x00\x00;";
        let e = err(gif);
        assert_eq!(
            e.to_string(),
            "unsupported image: GIF images are not accepted (send PNG, JPEG, PGM/PPM, TIFF or BMP)"
        );
    }

    #[test]
    fn empty_and_too_many_bytes() {
        assert_eq!(err(&[]), DecodeError::Empty);
        let png = encode(&DynamicImage::ImageLuma8(ramp8()), ImageFormat::Png);
        let limits = DecodeLimits {
            max_bytes: png.len() - 1,
            ..DecodeLimits::default()
        };
        assert_eq!(
            decode(&png, &limits),
            Err(DecodeError::TooManyBytes {
                bytes: png.len(),
                max: png.len() - 1
            })
        );
    }

    /// Rewrites a PNG's IHDR width and height and fixes the chunk's CRC, so that the file
    /// is valid up to its pixel data.
    fn patch_ihdr(png: &mut [u8], width: u32, height: u32) {
        // Signature (8), IHDR length (4) and type (4), then width and height.
        assert_eq!(&png[12..16], b"IHDR");
        png[16..20].copy_from_slice(&width.to_be_bytes());
        png[20..24].copy_from_slice(&height.to_be_bytes());
        let crc = crc32(&png[12..29]);
        png[29..33].copy_from_slice(&crc.to_be_bytes());
    }

    fn crc32(data: &[u8]) -> u32 {
        let mut crc = !0u32;
        for &b in data {
            crc ^= u32::from(b);
            for _ in 0..8 {
                crc = if crc & 1 == 1 {
                    (crc >> 1) ^ 0xEDB8_8320
                } else {
                    crc >> 1
                };
            }
        }
        !crc
    }

    #[test]
    fn decompression_bomb_is_refused_on_its_header() {
        let mut png = encode(&DynamicImage::ImageLuma8(ramp8()), ImageFormat::Png);
        patch_ihdr(&mut png, 100_000, 100_000);
        assert!(png.len() < 200);
        // Were the pixels allocated, this would ask for 10 GB and abort the test process.
        assert_eq!(
            err(&png),
            DecodeError::TooManyPixels {
                width: 100_000,
                height: 100_000,
                max: DecodeLimits::default().max_pixels
            }
        );
        // Just under the limit, the header passes and the missing pixel data is reported.
        patch_ihdr(&mut png, 1000, 1000);
        assert!(matches!(err(&png), DecodeError::Corrupt { .. }));
    }

    #[test]
    fn zero_sized_images_are_refused() {
        // The PNM decoder hands a 0 x 5 header on; the size check catches it.
        assert_eq!(
            err(b"P5\n0 5\n255\n"),
            DecodeError::ZeroSize {
                width: 0,
                height: 5
            }
        );
        // The PNG and BMP decoders refuse such headers themselves (the BMP one as an
        // unsupported "too large" size); either way it is an error, never an empty image.
        let mut png = encode(&DynamicImage::ImageLuma8(ramp8()), ImageFormat::Png);
        patch_ihdr(&mut png, 0, 5);
        assert!(matches!(err(&png), DecodeError::Corrupt { .. }));
        let mut bmp = encode(&DynamicImage::ImageLuma8(ramp8()), ImageFormat::Bmp);
        bmp[18..22].copy_from_slice(&0i32.to_le_bytes());
        assert!(decode(&bmp, &DecodeLimits::default()).is_err());
    }

    #[test]
    fn raw_buffers() {
        let limits = DecodeLimits::default();
        let g = from_raw(3, 2, &[0, 1, 2, 3, 4, 255], &limits).unwrap();
        assert_eq!(g.at(2, 1), 255.0);
        assert_eq!(
            from_raw(3, 2, &[0; 5], &limits),
            Err(DecodeError::RawSize {
                width: 3,
                height: 2,
                expected: 6,
                got: 5
            })
        );
        assert_eq!(
            from_raw(0, 2, &[], &limits),
            Err(DecodeError::ZeroSize {
                width: 0,
                height: 2
            })
        );
        assert_eq!(
            from_raw(u32::MAX, u32::MAX, &[1], &limits),
            Err(DecodeError::TooManyPixels {
                width: u32::MAX,
                height: u32::MAX,
                max: DecodeLimits::default().max_pixels
            })
        );
    }

    #[test]
    fn size_check() {
        let g = from_raw(3, 2, &[0; 6], &DecodeLimits::default()).unwrap();
        assert_eq!(check_size(&g, 3, 2), Ok(()));
        let e = check_size(&g, 640, 480).unwrap_err();
        assert_eq!(
            e,
            DecodeError::SizeMismatch {
                width: 3,
                height: 2,
                expected_width: 640,
                expected_height: 480
            }
        );
        assert_eq!(
            e.to_string(),
            "the image is 3 x 2 pixels but the camera's calibration is for 640 x 480"
        );
    }

    /// One valid file per format, for the mutation property.
    fn seeds() -> Vec<Vec<u8>> {
        let grey = DynamicImage::ImageLuma8(ramp8());
        let rgb = DynamicImage::ImageRgb8(rgb8());
        vec![
            encode(&grey, ImageFormat::Png),
            encode(&rgb, ImageFormat::Png),
            encode(&grey, ImageFormat::Jpeg),
            pnm(&grey),
            encode(&rgb, ImageFormat::Tiff),
            encode(&rgb, ImageFormat::Bmp),
        ]
    }

    /// Small limits keep mutated headers from making the test slow, not from crashing it.
    fn small_limits() -> DecodeLimits {
        DecodeLimits {
            max_bytes: 1 << 20,
            max_pixels: 1 << 20,
        }
    }

    #[test]
    fn a_jpeg_whose_colour_is_sampled_finer_than_its_luma_is_refused_not_a_panic() {
        // Found by the image_decode fuzz target: zune-jpeg 0.5.15's upsampler asserts on it.
        let bytes =
            include_bytes!("../../../../fuzz/corpus/image_decode/seed-regress-zune-jpeg-upsampler");
        let limits = DecodeLimits {
            max_bytes: 1 << 20,
            max_pixels: 1 << 20,
        };
        match decode(bytes, &limits) {
            Err(DecodeError::Corrupt { message, .. }) => {
                assert!(message.contains("sampling"), "{message}")
            }
            other => panic!("expected the sampling refused, got {other:?}"),
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2000))]

        #[test]
        fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..512)) {
            let _ = decode(&bytes, &small_limits());
        }

        #[test]
        fn format_magic_with_arbitrary_tail_never_panics(
            magic in prop::sample::select(vec![
                &b"\x89PNG\r\n\x1a\n"[..], &[0xff, 0xd8, 0xff][..], b"P5", b"P6", b"P2",
                b"II*\x00", b"MM\x00*", b"BM",
            ]),
            tail in proptest::collection::vec(any::<u8>(), 0..512),
        ) {
            let bytes = [magic, &tail[..]].concat();
            let _ = decode(&bytes, &small_limits());
        }

        #[test]
        fn mutated_valid_files_never_panic(
            seed in 0usize..6,
            edits in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..8),
            cut in any::<prop::sample::Index>(),
            truncate in any::<bool>(),
        ) {
            let mut bytes = seeds().swap_remove(seed);
            for (at, value) in edits {
                let i = at.index(bytes.len());
                bytes[i] = value;
            }
            if truncate {
                bytes.truncate(cut.index(bytes.len()));
            }
            let _ = decode(&bytes, &small_limits());
        }
    }
}
