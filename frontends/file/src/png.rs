//! Writing frames as PNG files.

/// Writes RGBA16 pixels (premultiplied over black) as a 16-bit RGB PNG.
pub fn save_png16(
    path: &std::path::Path,
    width: usize,
    height: usize,
    rgba: &[[u16; 4]],
) -> Result<(), image::ImageError> {
    let rgb: Vec<u16> = rgba.iter().flat_map(|p| [p[0], p[1], p[2]]).collect();
    let img =
        image::ImageBuffer::<image::Rgb<u16>, Vec<u16>>::from_raw(width as u32, height as u32, rgb)
            .ok_or_else(|| {
                image::ImageError::Parameter(image::error::ParameterError::from_kind(
                    image::error::ParameterErrorKind::DimensionMismatch,
                ))
            })?;
    img.save_with_format(path, image::ImageFormat::Png)
}

/// Writes RGBA8 pixels (premultiplied over black) as an RGB PNG.
pub fn save_png(
    path: &std::path::Path,
    width: usize,
    height: usize,
    rgba: &[[u8; 4]],
) -> Result<(), image::ImageError> {
    let rgb: Vec<u8> = rgba.iter().flat_map(|p| [p[0], p[1], p[2]]).collect();
    image::save_buffer(
        path,
        &rgb,
        width as u32,
        height as u32,
        image::ExtendedColorType::Rgb8,
    )
}
