//! Depth images out as OpenEXR and back in: one single-layer file per image,
//! `<stem>.depth-xmin.exr` .. `<stem>.depth-zmax.exr`.
//!
//! Each file holds a camera on one face of the grid looking into it along the axis (`min`: on
//! the min face looking +axis, D⁻; `max`: on the max face looking −axis, D⁺). Channels, f32,
//! same pixel order as [`DepthImage`] (row 0 = top line of the file):
//! - `Z`: world-unit distance from the camera plane along the view direction, rounded toward
//!   the camera (so a value read back never puts the surface farther than the truth); an empty
//!   pixel is +inf.
//! - `Y`: 1 − Z / (axis length) for hits (near = bright), 0 for empty: for image viewers only.
//!
//! The header carries [`DepthMeta`] as JSON in `sweptvol:meta`, and its fields as separate
//! attributes (`sweptvol:axis`, `sweptvol:voxelSize`, ...). serde_json (built without its
//! `float_roundtrip` feature) may parse a float one ulp off, so the reader takes every float
//! from its own attribute (binary f64, or text written with 17 significant digits), which
//! round-trips exactly, after checking that the JSON agrees.

use std::path::{Path, PathBuf};

use anyhow::{bail, ensure, Context};
use exr::prelude::{
    read_first_flat_layer_from_file, AnyChannel, AnyChannels, AttributeValue, Encoding,
    FlatSamples, Image, Layer, LayerAttributes, SmallVec, Text, WritableImage,
};
use serde::{Deserialize, Serialize};

use crate::depth::{image_size, DepthImage, DepthImages, AXIS_NAMES, COLUMN_AXIS, ROW_AXIS};
use crate::input::grid::{Grid, MAX_RESOLUTION};
use crate::io::atomic::Staged;

/// Attribute holding the whole [`DepthMeta`] as JSON text.
pub const META_ATTRIBUTE: &str = "sweptvol:meta";
/// How an empty pixel is stored (also written into [`DepthMeta::empty`]).
pub const EMPTY_DESCRIPTION: &str = "Z = +inf, Y = 0";

/// Which of an axis's two images.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Side {
    /// D⁻: camera on the grid's min face looking along +axis (`xmin`).
    Min,
    /// D⁺: camera on the grid's max face looking along −axis (`xmax`).
    Max,
}

impl Side {
    pub const BOTH: [Side; 2] = [Side::Min, Side::Max];

    /// "min" or "max".
    pub fn name(self) -> &'static str {
        match self {
            Side::Min => "min",
            Side::Max => "max",
        }
    }
}

/// What one depth EXR says about itself. World units unless noted.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DepthMeta {
    /// sweptvol version that wrote the file.
    pub version: String,
    /// Ray axis: "x", "y" or "z".
    pub axis: String,
    /// "min" (D⁻) or "max" (D⁺).
    pub side: String,
    /// "+x" for a min image (camera on the min face), "-x" for a max image.
    pub view_direction: String,
    /// Coordinate along the axis of the face the camera sits on.
    pub camera_plane: f64,
    /// Voxel edge h.
    pub voxel_size: f64,
    /// Where the ray of pixel (0, 0) leaves the camera plane.
    pub pixel00_centre: [f64; 3],
    /// From pixel (col, row) to (col + 1, row): +h along the column axis.
    pub column_step: [f64; 3],
    /// From pixel (col, row) to (col, row + 1): −h along the row axis (rows run downward).
    pub row_step: [f64; 3],
    /// Pixels per row.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// World position of the grid's min corner.
    pub grid_origin: [f64; 3],
    /// Voxels along x, y, z.
    pub grid_dims: [u32; 3],
    /// Offset radius δ.
    pub delta: f64,
    /// Rounding term added to δ.
    pub rounding: f64,
    /// Voxels along the grid's longest edge (the paper's n).
    pub resolution: u32,
    /// How an empty pixel is stored: [`EMPTY_DESCRIPTION`].
    pub empty: String,
}

impl DepthMeta {
    /// The metadata of image (`axis`, `side`) on `grid`.
    pub fn new(grid: &Grid, axis: usize, side: Side, extra: &ExtraMeta) -> Self {
        let h = grid.h;
        let (column, row) = (COLUMN_AXIS[axis], ROW_AXIS[axis]);
        let (width, height) = image_size(grid, axis);
        let (sign, camera_plane) = match side {
            Side::Min => ("+", grid.origin[axis]),
            Side::Max => ("-", grid.origin[axis] + grid.dims[axis] as f64 * h),
        };
        let mut pixel00_centre = [0.0; 3];
        pixel00_centre[axis] = camera_plane;
        pixel00_centre[column] = grid.origin[column] + 0.5 * h;
        pixel00_centre[row] = grid.origin[row] + (height as f64 - 0.5) * h;
        let mut column_step = [0.0; 3];
        column_step[column] = h;
        let mut row_step = [0.0; 3];
        row_step[row] = -h;
        DepthMeta {
            version: env!("CARGO_PKG_VERSION").to_string(),
            axis: AXIS_NAMES[axis].to_string(),
            side: side.name().to_string(),
            view_direction: format!("{sign}{}", AXIS_NAMES[axis]),
            camera_plane,
            voxel_size: h,
            pixel00_centre,
            column_step,
            row_step,
            width,
            height,
            grid_origin: grid.origin,
            grid_dims: grid.dims,
            delta: extra.delta,
            rounding: extra.rounding,
            resolution: grid.resolution(),
            empty: EMPTY_DESCRIPTION.to_string(),
        }
    }

    /// The grid the image was rendered on.
    pub fn grid(&self) -> Grid {
        Grid {
            origin: self.grid_origin,
            h: self.voxel_size,
            dims: self.grid_dims,
        }
    }

    fn extra(&self) -> ExtraMeta {
        ExtraMeta {
            delta: self.delta,
            rounding: self.rounding,
        }
    }
}

/// What the files record besides the images and their grid, world units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ExtraMeta {
    /// Offset radius δ.
    pub delta: f64,
    /// Rounding term added to δ.
    pub rounding: f64,
}

/// `<stem>.depth-xmin.exr`, or `depth-xmin.exr` for an empty stem.
pub fn depth_file_name(stem: &str, axis: usize, side: Side) -> String {
    let name = format!("depth-{}{}.exr", AXIS_NAMES[axis], side.name());
    if stem.is_empty() {
        name
    } else {
        format!("{stem}.{name}")
    }
}

/// Write image (`axis`, `side`) of `images` to `path` (ZIP, lossless), in place and without
/// fsync: [`write_all`] makes the files durable and atomic.
pub fn write_depth_exr(
    path: &Path,
    images: &DepthImages,
    axis: usize,
    side: Side,
    extra: &ExtraMeta,
) -> anyhow::Result<()> {
    let open =
        || std::fs::File::create(path).with_context(|| format!("cannot write {}", path.display()));
    write_depth_exr_to(open, path, images, axis, side, extra)
}

/// [`write_depth_exr`] into the file `open` gives once the images are checked (`path` names it
/// in errors).
fn write_depth_exr_to(
    open: impl FnOnce() -> anyhow::Result<std::fs::File>,
    path: &Path,
    images: &DepthImages,
    axis: usize,
    side: Side,
    extra: &ExtraMeta,
) -> anyhow::Result<()> {
    ensure!(axis < 3, "axis {axis} is not 0, 1 or 2");
    ensure!(
        extra.delta.is_finite() && extra.rounding.is_finite(),
        "δ = {} and rounding = {} must be finite",
        extra.delta,
        extra.rounding
    );
    let grid = &images.grid;
    let image = &images.images[axis];
    check_image(grid, image, axis)?;
    let axis_len = grid.dims[axis] as f64;
    let depths = match side {
        Side::Min => &image.min,
        Side::Max => &image.max,
    };
    let z: Vec<f32> = depths
        .iter()
        .map(|&t| depth_to_z(t, side, axis_len, grid.h))
        .collect();
    let y: Vec<f32> = z
        .iter()
        .map(|&z| {
            if z.is_finite() {
                (1.0 - z as f64 / (axis_len * grid.h)) as f32
            } else {
                0.0
            }
        })
        .collect();

    let meta = DepthMeta::new(grid, axis, side, extra);
    let mut attributes = LayerAttributes {
        software_name: Some(text(&format!("sweptvol {}", meta.version))?),
        ..LayerAttributes::default()
    };
    for (name, value) in header_attributes(&meta)? {
        attributes.other.insert(text(name)?, value);
    }
    let channels = AnyChannels::sort(SmallVec::from_vec(vec![
        AnyChannel::new("Y", FlatSamples::F32(y)),
        AnyChannel::new("Z", FlatSamples::F32(z)),
    ]));
    let size = (image.width as usize, image.height as usize);
    let layer = Layer::new(size, attributes, Encoding::SMALL_LOSSLESS, channels);

    let mut bytes = std::io::Cursor::new(Vec::new());
    Image::from_layer(layer)
        .write()
        .to_buffered(&mut bytes)
        .with_context(|| format!("cannot encode {}", path.display()))?;
    let mut bytes = bytes.into_inner();
    sort_header_attributes(&mut bytes)?;
    let mut file = open()?;
    std::io::Write::write_all(&mut file, &bytes)
        .with_context(|| format!("cannot write {}", path.display()))
}

/// The exr crate writes custom attributes in `HashMap` order, which differs from map to map:
/// sort the header's attributes by name (as OpenEXR itself writes them) so that equal images give
/// equal files. The header keeps its length, so the chunk offsets after it stay valid.
/// Layout (single-part file): magic and version (8 bytes), then per attribute its name and type
/// name (NUL-terminated), an i32 size and the value, and a NUL after the last one.
fn sort_header_attributes(bytes: &mut [u8]) -> anyhow::Result<()> {
    let nul_after = |from: usize| -> anyhow::Result<usize> {
        let rest = bytes.get(from..).context("EXR header ends early")?;
        Ok(from
            + rest
                .iter()
                .position(|&b| b == 0)
                .context("EXR header ends early")?)
    };
    let mut attributes: Vec<(&[u8], &[u8])> = Vec::new();
    let mut at = 8;
    loop {
        let name_end = nul_after(at)?;
        if name_end == at {
            break;
        }
        let type_end = nul_after(name_end + 1)?;
        let size = bytes
            .get(type_end + 1..type_end + 5)
            .context("EXR header ends early")?;
        let size = i32::from_le_bytes(size.try_into()?);
        ensure!(size >= 0, "negative EXR attribute size");
        let end = type_end + 5 + size as usize;
        ensure!(end <= bytes.len(), "EXR header ends early");
        attributes.push((&bytes[at..name_end], &bytes[at..end]));
        at = end;
    }
    attributes.sort();
    let sorted: Vec<u8> = attributes
        .iter()
        .flat_map(|(_, a)| a.iter().copied())
        .collect();
    bytes[8..8 + sorted.len()].copy_from_slice(&sorted);
    Ok(())
}

/// Stage the six images for `dir` under temporary names in `staged` (renamed into place by
/// its `commit`), returning their final paths in order xmin, xmax, ymin, ymax, zmin, zmax.
pub fn stage_all(
    staged: &mut Staged,
    dir: &Path,
    stem: &str,
    images: &DepthImages,
    extra: &ExtraMeta,
) -> anyhow::Result<Vec<PathBuf>> {
    let mut paths = Vec::with_capacity(6);
    for axis in 0..3 {
        for side in Side::BOTH {
            let path = dir.join(depth_file_name(stem, axis, side));
            write_depth_exr_to(|| staged.create(&path), &path, images, axis, side, extra)?;
            paths.push(path);
        }
    }
    Ok(paths)
}

/// Write the six images into `dir` atomically (see [`stage_all`]).
pub fn write_all(
    dir: &Path,
    stem: &str,
    images: &DepthImages,
    extra: &ExtraMeta,
) -> anyhow::Result<Vec<PathBuf>> {
    let mut staged = Staged::default();
    let paths = stage_all(&mut staged, dir, stem, images, extra)?;
    staged.commit()?;
    Ok(paths)
}

/// Read one depth EXR: its metadata and its `Z` channel (world units, row-major from the top
/// row, +inf = empty).
pub fn read_depth_exr(path: &Path) -> anyhow::Result<(DepthMeta, Vec<f32>)> {
    let read = || -> anyhow::Result<(DepthMeta, Vec<f32>)> {
        // The header first: a depth image is at most MAX_RESOLUTION pixels a side, and a
        // damaged size must be refused before the decoder allocates for it.
        let headers = exr::meta::MetaData::read_from_file(path, false)?.headers;
        for h in headers.iter() {
            let (w, ht) = (h.layer_size.0, h.layer_size.1);
            ensure!(
                w <= MAX_RESOLUTION as usize && ht <= MAX_RESOLUTION as usize,
                "the image claims {w}x{ht} pixels, more than any sweptvol grid ({MAX_RESOLUTION} a side): the file is damaged or not a sweptvol depth image"
            );
        }
        let layer = read_first_flat_layer_from_file(path)?.layer_data;
        let attrs = &layer.attributes.other;
        let json = match attrs.get(META_ATTRIBUTE.as_bytes()) {
            Some(AttributeValue::Text(json)) => json.to_string(),
            _ => bail!("no text attribute `{META_ATTRIBUTE}`: not a sweptvol depth image"),
        };
        let mut meta: DepthMeta =
            serde_json::from_str(&json).with_context(|| format!("bad `{META_ATTRIBUTE}`"))?;
        take_exact_floats(&mut meta, attrs)?;
        let size = (meta.width as usize, meta.height as usize);
        ensure!(
            (layer.size.0, layer.size.1) == size,
            "the image is {}x{} pixels but its metadata says {}x{}",
            layer.size.0,
            layer.size.1,
            size.0,
            size.1
        );
        let z = layer
            .channel_data
            .list
            .into_iter()
            .find(|channel| channel.name.eq("Z"))
            .context("no channel `Z`")?;
        match z.sample_data {
            FlatSamples::F32(z) => Ok((meta, z)),
            _ => bail!("channel `Z` is not 32-bit float"),
        }
    };
    read().with_context(|| format!("cannot read depth image {}", path.display()))
}

/// Read the six files written by [`write_all`] back into grid units, rounding outward: every
/// D⁻ read back is <= the one written, within 2 ulps; every D⁺ is >= the one written, within
/// 2 ulps of its distance from the max face (the quantity the file stores), so near the min
/// face its error is some f32 steps of the axis length. Errors if a file is missing, holds
/// another image, or was rendered on another grid or with other parameters.
pub fn read_all(dir: &Path, stem: &str) -> anyhow::Result<(DepthImages, ExtraMeta)> {
    let mut files = Vec::with_capacity(6);
    for (axis, axis_name) in AXIS_NAMES.into_iter().enumerate() {
        for side in Side::BOTH {
            let path = dir.join(depth_file_name(stem, axis, side));
            let (meta, z) = read_depth_exr(&path)?;
            ensure!(
                meta.axis == axis_name && meta.side == side.name(),
                "{} holds the {}{} image, not the {axis_name}{} one",
                path.display(),
                meta.axis,
                meta.side,
                side.name()
            );
            files.push((path, axis, side, meta, z));
        }
    }
    let (first_path, _, _, first, _) = &files[0];
    let (grid, extra) = (first.grid(), first.extra());
    ensure!(
        grid.h.is_finite()
            && grid.h > 0.0
            && grid.origin.iter().all(|o| o.is_finite())
            && grid.dims.iter().all(|&d| d >= 1),
        "{} has an invalid grid {grid:?}",
        first_path.display()
    );
    let mut images = DepthImages::empty(grid);
    for (path, axis, side, meta, z) in &files {
        ensure!(
            meta.grid() == grid && meta.extra() == extra,
            "{} and {} come from different sweeps: grid {:?}, {:?} vs grid {grid:?}, {extra:?}",
            path.display(),
            first_path.display(),
            meta.grid(),
            meta.extra()
        );
        let image = &mut images.images[*axis];
        ensure!(
            (meta.width, meta.height) == (image.width, image.height) && z.len() == image.min.len(),
            "{} is {}x{} pixels ({} values) but its grid needs {}x{}",
            path.display(),
            meta.width,
            meta.height,
            z.len(),
            image.width,
            image.height
        );
        let axis_len = grid.dims[*axis] as f64;
        let target = match side {
            Side::Min => &mut image.min,
            Side::Max => &mut image.max,
        };
        for (t, &z) in target.iter_mut().zip(z) {
            *t = z_to_depth(z, *side, axis_len, grid.h);
        }
    }
    Ok((images, extra))
}

fn check_image(grid: &Grid, image: &DepthImage, axis: usize) -> anyhow::Result<()> {
    let (width, height) = image_size(grid, axis);
    let n = width as usize * height as usize;
    ensure!(
        image.axis == axis
            && (image.width, image.height) == (width, height)
            && image.min.len() == n
            && image.max.len() == n,
        "depth image {axis} (axis {}, {}x{}, {}/{} values) does not fit its grid ({width}x{height})",
        image.axis,
        image.width,
        image.height,
        image.min.len(),
        image.max.len()
    );
    Ok(())
}

/// World distance from the camera plane of `side` to grid coordinate `t` along an axis of
/// `axis_len` voxels of edge `h`, rounded toward the camera. Empty (min +inf, max −inf) gives
/// +inf.
fn depth_to_z(t: f32, side: Side, axis_len: f64, h: f64) -> f32 {
    let along = match side {
        Side::Min => t as f64,
        Side::Max => axis_len - t as f64,
    };
    f32_down(along * h)
}

/// Inverse of [`depth_to_z`] in grid units, rounded outward (D⁻ down, D⁺ up). +inf gives the
/// empty value of `side`.
fn z_to_depth(z: f32, side: Side, axis_len: f64, h: f64) -> f32 {
    let along = z as f64 / h;
    match side {
        Side::Min => f32_down(along),
        Side::Max => f32_up(axis_len - along),
    }
}

/// Largest f32 <= `x`; ±inf and NaN map to themselves.
fn f32_down(x: f64) -> f32 {
    let f = x as f32;
    if f as f64 > x {
        next_down(f)
    } else {
        f
    }
}

/// Smallest f32 >= `x`.
fn f32_up(x: f64) -> f32 {
    -f32_down(-x)
}

/// The f32 just below `f` (not NaN, not −inf): `f32::next_down`, stable only from Rust 1.86.
fn next_down(f: f32) -> f32 {
    if f == 0.0 {
        -f32::from_bits(1)
    } else if f > 0.0 {
        f32::from_bits(f.to_bits() - 1)
    } else {
        f32::from_bits(f.to_bits() + 1)
    }
}

/// Scalar float fields and their binary f64 attributes.
const F64_ATTRIBUTES: [&str; 4] = [
    "sweptvol:cameraPlane",
    "sweptvol:voxelSize",
    "sweptvol:delta",
    "sweptvol:rounding",
];
/// Vector float fields and their text attributes "x y z".
const VEC3_ATTRIBUTES: [&str; 4] = [
    "sweptvol:pixel00Centre",
    "sweptvol:columnStep",
    "sweptvol:rowStep",
    "sweptvol:gridOrigin",
];

fn f64_fields(meta: &mut DepthMeta) -> [&mut f64; 4] {
    [
        &mut meta.camera_plane,
        &mut meta.voxel_size,
        &mut meta.delta,
        &mut meta.rounding,
    ]
}

fn vec3_fields(meta: &mut DepthMeta) -> [&mut [f64; 3]; 4] {
    [
        &mut meta.pixel00_centre,
        &mut meta.column_step,
        &mut meta.row_step,
        &mut meta.grid_origin,
    ]
}

/// The header attributes besides the standard ones, in writing order.
fn header_attributes(meta: &DepthMeta) -> anyhow::Result<Vec<(&'static str, AttributeValue)>> {
    // A copy, as the field lists lend `&mut` (for the reader's `take_exact_floats`).
    let mut meta = meta.clone();
    let mut out = vec![
        (META_ATTRIBUTE, text_value(&serde_json::to_string(&meta)?)?),
        ("sweptvol:version", text_value(&meta.version)?),
        ("sweptvol:axis", text_value(&meta.axis)?),
        ("sweptvol:side", text_value(&meta.side)?),
        ("sweptvol:viewDirection", text_value(&meta.view_direction)?),
    ];
    for (name, value) in F64_ATTRIBUTES.into_iter().zip(f64_fields(&mut meta)) {
        out.push((name, AttributeValue::F64(*value)));
    }
    for (name, value) in VEC3_ATTRIBUTES.into_iter().zip(vec3_fields(&mut meta)) {
        let [x, y, z] = *value;
        out.push((name, text_value(&format!("{x:.17e} {y:.17e} {z:.17e}"))?));
    }
    Ok(out)
}

/// Replace the JSON's floats with the exact ones of their own attributes, which must agree.
fn take_exact_floats(
    meta: &mut DepthMeta,
    attrs: &std::collections::HashMap<Text, AttributeValue>,
) -> anyhow::Result<()> {
    for (name, json) in F64_ATTRIBUTES.into_iter().zip(f64_fields(meta)) {
        let exact = match attrs.get(name.as_bytes()) {
            Some(AttributeValue::F64(value)) => *value,
            _ => bail!("no double attribute `{name}`"),
        };
        take_exact(json, exact, name)?;
    }
    for (name, json) in VEC3_ATTRIBUTES.into_iter().zip(vec3_fields(meta)) {
        let parsed = match attrs.get(name.as_bytes()) {
            Some(AttributeValue::Text(value)) => value
                .to_string()
                .split_whitespace()
                .map(str::parse::<f64>)
                .collect::<Result<Vec<f64>, _>>()
                .ok(),
            _ => None,
        };
        let Some(&[x, y, z]) = parsed.as_deref() else {
            bail!("no text attribute `{name}` of three numbers");
        };
        for (json, exact) in json.iter_mut().zip([x, y, z]) {
            take_exact(json, exact, name)?;
        }
    }
    Ok(())
}

fn take_exact(json: &mut f64, exact: f64, name: &str) -> anyhow::Result<()> {
    ensure!(
        (exact - *json).abs() <= 1e-15 * exact.abs(),
        "`{name}` = {exact:e} disagrees with `{META_ATTRIBUTE}` ({json:e})"
    );
    *json = exact;
    Ok(())
}

fn text(s: &str) -> anyhow::Result<Text> {
    Text::new_or_none(s).with_context(|| format!("{s:?} has characters an EXR text cannot hold"))
}

fn text_value(s: &str) -> anyhow::Result<AttributeValue> {
    Ok(AttributeValue::Text(text(s)?))
}

#[cfg(test)]
mod tests {
    use super::*;
    use exr::prelude::{Compression, LineOrder};
    use std::fs;

    const EXTRA: ExtraMeta = ExtraMeta {
        delta: 0.031_234_567_890_123_45,
        rounding: 1.0e-5 / 3.0,
    };

    fn grid() -> Grid {
        Grid {
            origin: [-1.5, 0.25, 3.0],
            h: 0.01,
            dims: [7, 5, 3],
        }
    }

    /// Images with empty pixels, values on the faces, and values whose products with h are
    /// not f32s.
    fn sample_images(grid: Grid) -> DepthImages {
        let mut images = DepthImages::empty(grid);
        for image in &mut images.images {
            let len = grid.dims[image.axis] as f32;
            for i in 0..image.min.len() {
                let (lo, hi) = match i % 5 {
                    0 => continue,
                    1 => (0.0, len),
                    2 => (1.0 / 3.0, len - 0.1),
                    3 => (i as f32 * 0.137 % len * 0.5, len * 0.9),
                    _ => (0.5, 0.5),
                };
                image.min[i] = lo;
                image.max[i] = hi;
            }
        }
        images
    }

    /// Distance in representable f32 steps.
    fn ulps(a: f32, b: f32) -> i64 {
        let key = |f: f32| {
            let i = f.to_bits() as i32 as i64;
            if i < 0 {
                i32::MIN as i64 - i
            } else {
                i
            }
        };
        (key(a) - key(b)).abs()
    }

    /// Spacing of the f32s at |x|.
    fn spacing(x: f32) -> f64 {
        let a = x.abs();
        f32::from_bits(a.to_bits() + 1) as f64 - a as f64
    }

    /// D⁻ comes back within 2 ulps below. D⁺ is stored as a distance from the max face, so it
    /// comes back within 2 ulps of `len - max` above (absolute error ~ f32 steps of `len`).
    fn assert_close(min: f32, max: f32, original: (f32, f32), len: f32) {
        let (omin, omax) = original;
        assert!(min <= omin && ulps(min, omin) <= 2, "min {omin} -> {min}");
        let tolerance = 2.0 * (spacing(len - omax) + spacing(omax));
        assert!(
            max >= omax && (max - omax) as f64 <= tolerance,
            "max {omax} -> {max}"
        );
    }

    fn assert_outward(original: &DepthImages, back: &DepthImages) {
        for (o, b) in original.images.iter().zip(&back.images) {
            let len = original.grid.dims[o.axis] as f32;
            for i in 0..o.min.len() {
                if o.is_empty_at(i) {
                    assert_eq!((b.min[i], b.max[i]), (f32::INFINITY, f32::NEG_INFINITY));
                } else {
                    assert_close(b.min[i], b.max[i], (o.min[i], o.max[i]), len);
                }
            }
        }
    }

    #[test]
    fn file_names() {
        assert_eq!(depth_file_name("part", 0, Side::Min), "part.depth-xmin.exr");
        assert_eq!(depth_file_name("a.b", 2, Side::Max), "a.b.depth-zmax.exr");
        assert_eq!(depth_file_name("", 1, Side::Max), "depth-ymax.exr");
    }

    #[test]
    fn rounding_is_outward_and_tight() {
        let hs = [
            0.01,
            0.1 + 0.2,
            1.0 / 3.0,
            0.017_453_292_519_943_295,
            7.3e-4,
        ];
        for h in hs {
            for len in [1.0, 3.0, 129.0, 16384.0] {
                for k in 0..=2000 {
                    let t = (k as f64 / 2000.0 * len) as f32;
                    let min = z_to_depth(depth_to_z(t, Side::Min, len, h), Side::Min, len, h);
                    let max = z_to_depth(depth_to_z(t, Side::Max, len, h), Side::Max, len, h);
                    assert_close(min, max, (t, t), len as f32);
                    // Z itself never lies beyond the true distance.
                    assert!(
                        depth_to_z(t, Side::Min, len, h) as f64 <= t as f64 * h * (1.0 + 1e-15)
                    );
                }
            }
        }
        assert_eq!(f32_down(0.1), 0.099_999_994);
        assert_eq!(f32_up(0.1), 0.1);
        assert_eq!(f32_down(-0.0), -0.0);
        assert_eq!(f32_down(-1e-50), -f32::from_bits(1));
        assert_eq!(f32_down(1e300), f32::MAX);
        assert_eq!(f32_up(-1e300), f32::MIN);
        assert_eq!(
            depth_to_z(f32::INFINITY, Side::Min, 3.0, 0.1),
            f32::INFINITY
        );
        assert_eq!(
            depth_to_z(f32::NEG_INFINITY, Side::Max, 3.0, 0.1),
            f32::INFINITY
        );
        assert_eq!(
            z_to_depth(f32::INFINITY, Side::Min, 3.0, 0.1),
            f32::INFINITY
        );
        assert_eq!(
            z_to_depth(f32::INFINITY, Side::Max, 3.0, 0.1),
            f32::NEG_INFINITY
        );
    }

    #[test]
    fn write_all_then_read_all_round_trips_outward() {
        let dir = tempfile::tempdir().unwrap();
        let images = sample_images(grid());
        let paths = write_all(dir.path(), "part", &images, &EXTRA).unwrap();
        let names = [
            "part.depth-xmin.exr",
            "part.depth-xmax.exr",
            "part.depth-ymin.exr",
            "part.depth-ymax.exr",
            "part.depth-zmin.exr",
            "part.depth-zmax.exr",
        ];
        let expected: Vec<PathBuf> = names.iter().map(|n| dir.path().join(n)).collect();
        assert_eq!(paths, expected);
        let mut listed: Vec<String> = fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        listed.sort();
        let mut sorted = names.map(String::from).to_vec();
        sorted.sort();
        assert_eq!(listed, sorted, "no temporary files left behind");

        let (back, extra) = read_all(dir.path(), "part").unwrap();
        assert_eq!(back.grid, images.grid);
        assert_eq!(extra, EXTRA);
        assert_outward(&images, &back);
    }

    #[test]
    fn awkward_floats_round_trip_exactly() {
        // serde_json's default parser reads each of these 17-digit floats one ulp off.
        let grid = Grid {
            origin: [-1.5, 0.003_768_985_558_851_594_6, 2.0f64.sqrt()],
            h: 0.003_682_507_711_262_123_6,
            dims: [4, 9, 2],
        };
        let extra = ExtraMeta {
            delta: 0.003_728_793_563_445_037_4,
            rounding: 0.003_710_405_666_227_940_4,
        };
        let dir = tempfile::tempdir().unwrap();
        let images = sample_images(grid);
        write_all(dir.path(), "", &images, &extra).unwrap();
        let (back, back_extra) = read_all(dir.path(), "").unwrap();
        assert_eq!(back.grid, grid);
        assert_eq!(back_extra, extra);
        assert_outward(&images, &back);
    }

    #[test]
    fn metadata_describes_the_cameras() {
        let dir = tempfile::tempdir().unwrap();
        let grid = grid();
        let images = sample_images(grid);
        write_all(dir.path(), "m", &images, &EXTRA).unwrap();
        let h = grid.h;
        let close = |a: [f64; 3], b: [f64; 3]| (0..3).all(|i| (a[i] - b[i]).abs() < 1e-12);
        for axis in 0..3 {
            let (c, r) = (COLUMN_AXIS[axis], ROW_AXIS[axis]);
            for side in Side::BOTH {
                let path = dir.path().join(depth_file_name("m", axis, side));
                let (meta, z) = read_depth_exr(&path).unwrap();
                let (width, height) = image_size(&grid, axis);
                assert_eq!((meta.width, meta.height), (width, height));
                assert_eq!(z.len(), (width * height) as usize);
                assert_eq!(meta.axis, AXIS_NAMES[axis]);
                assert_eq!(meta.side, side.name());
                assert_eq!(meta.version, env!("CARGO_PKG_VERSION"));
                assert_eq!(meta.empty, "Z = +inf, Y = 0");
                assert_eq!((meta.grid_origin, meta.grid_dims), (grid.origin, grid.dims));
                assert_eq!((meta.voxel_size, meta.resolution), (h, 7));
                assert_eq!((meta.delta, meta.rounding), (EXTRA.delta, EXTRA.rounding));
                let (sign, plane) = match side {
                    Side::Min => ('+', grid.origin[axis]),
                    Side::Max => ('-', grid.origin[axis] + grid.dims[axis] as f64 * h),
                };
                assert_eq!(meta.view_direction, format!("{sign}{}", AXIS_NAMES[axis]));
                assert!((meta.camera_plane - plane).abs() < 1e-12);
                let mut p00 = [0.0; 3];
                p00[axis] = plane;
                p00[c] = grid.origin[c] + 0.5 * h;
                p00[r] = grid.origin[r] + (height as f64 - 0.5) * h;
                assert!(close(meta.pixel00_centre, p00), "{:?}", meta.pixel00_centre);
                let (mut col, mut row) = ([0.0; 3], [0.0; 3]);
                col[c] = h;
                row[r] = -h;
                assert!(close(meta.column_step, col) && close(meta.row_step, row));
                // Z is the distance from the camera plane: pixel 1 spans the whole axis,
                // pixel 4 is a point half a voxel from the min face.
                let len = grid.dims[axis] as f64 * h;
                assert!(z[0].is_infinite() && z[5].is_infinite());
                assert_eq!(z[1], 0.0);
                let z4 = match side {
                    Side::Min => 0.5 * h,
                    Side::Max => (grid.dims[axis] as f64 - 0.5) * h,
                };
                assert!(
                    z[4] as f64 <= z4 && z4 - z[4] as f64 <= z4 * f32::EPSILON as f64,
                    "{} vs {z4}",
                    z[4]
                );
                assert!(z.iter().all(|&z| z.is_infinite() || z as f64 <= len));
            }
        }
    }

    #[test]
    fn files_are_plain_exr_with_y_and_z() {
        let dir = tempfile::tempdir().unwrap();
        let images = sample_images(grid());
        write_all(dir.path(), "g", &images, &EXTRA).unwrap();
        let path = dir.path().join("g.depth-zmax.exr");
        let layer = read_first_flat_layer_from_file(&path).unwrap().layer_data;
        let names: Vec<String> = layer
            .channel_data
            .list
            .iter()
            .map(|c| c.name.to_string())
            .collect();
        assert_eq!(names, ["Y", "Z"]);
        for channel in &layer.channel_data.list {
            assert!(matches!(channel.sample_data, FlatSamples::F32(_)));
        }
        assert_eq!(layer.size, exr::prelude::Vec2(7, 5));
        assert_eq!(layer.encoding.compression, Compression::ZIP16);
        assert_eq!(layer.encoding.line_order, LineOrder::Increasing);
        let attrs = &layer.attributes.other;
        assert!(matches!(
            attrs.get("sweptvol:voxelSize".as_bytes()),
            Some(AttributeValue::F64(h)) if *h == 0.01
        ));
        for name in ["sweptvol:axis", "sweptvol:side", "sweptvol:viewDirection"] {
            assert!(matches!(
                attrs.get(name.as_bytes()),
                Some(AttributeValue::Text(_))
            ));
        }
        let Some(AttributeValue::Text(dir_text)) = attrs.get("sweptvol:viewDirection".as_bytes())
        else {
            unreachable!()
        };
        assert_eq!(dir_text.to_string(), "-z");
        // Y: near = bright, empty = 0.
        let FlatSamples::F32(y) = &layer.channel_data.list[0].sample_data else {
            panic!("Y is not f32")
        };
        assert_eq!(y[0], 0.0);
        assert_eq!(y[1], 1.0);
    }

    #[test]
    fn mismatched_or_missing_files_are_errors() {
        let dir = tempfile::tempdir().unwrap();
        let images = sample_images(grid());
        write_all(dir.path(), "s", &images, &EXTRA).unwrap();
        // Another grid's y max image in place of this one's.
        let other = sample_images(Grid { h: 0.02, ..grid() });
        let path = dir.path().join("s.depth-ymax.exr");
        write_depth_exr(&path, &other, 1, Side::Max, &EXTRA).unwrap();
        let err = format!("{:#}", read_all(dir.path(), "s").unwrap_err());
        assert!(
            err.contains("different sweeps") && err.contains("s.depth-ymax.exr"),
            "{err}"
        );
        // An image of the wrong side.
        write_depth_exr(&path, &images, 1, Side::Min, &EXTRA).unwrap();
        let err = format!("{:#}", read_all(dir.path(), "s").unwrap_err());
        assert!(err.contains("holds the ymin image"), "{err}");
        // A missing file.
        fs::remove_file(&path).unwrap();
        let err = format!("{:#}", read_all(dir.path(), "s").unwrap_err());
        assert!(err.contains("s.depth-ymax.exr"), "{err}");
        // Images that do not fit their grid are refused before anything is written.
        let mut bad = images.clone();
        bad.images[2].min.pop();
        assert!(write_depth_exr(&dir.path().join("bad.exr"), &bad, 2, Side::Min, &EXTRA).is_err());
        assert!(!dir.path().join("bad.exr").exists());
    }

    /// Equal images give equal files: the exr crate's attribute order (a `HashMap`'s) differs
    /// from map to map, and the header is sorted by name after it.
    #[test]
    fn equal_images_give_byte_identical_files() {
        let dir = tempfile::tempdir().unwrap();
        let images = sample_images(grid());
        let files: Vec<Vec<u8>> = (0..6)
            .map(|i| {
                let path = dir.path().join(format!("{i}.exr"));
                write_depth_exr(&path, &images, 1, Side::Max, &EXTRA).unwrap();
                read_depth_exr(&path).unwrap();
                fs::read(&path).unwrap()
            })
            .collect();
        assert!(files.iter().all(|f| *f == files[0]), "files differ");
        let find = |name: &[u8]| {
            files[0]
                .windows(name.len())
                .position(|w| w == name)
                .unwrap()
        };
        assert!(find(b"channels\0") < find(b"sweptvol:axis\0"));
        assert!(find(b"sweptvol:axis\0") < find(b"sweptvol:voxelSize\0"));
    }

    /// A damaged data window (here claiming 808 million pixels a side, as a fuzzed file did) is
    /// refused from the header, before the decoder spends seconds and gigabytes on it.
    #[test]
    fn a_damaged_image_size_is_refused_from_the_header() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.depth-xmin.exr");
        write_depth_exr(&path, &sample_images(grid()), 0, Side::Min, &EXTRA).unwrap();
        let mut bytes = fs::read(&path).unwrap();
        let at = bytes.windows(10).position(|w| w == b"dataWindow").unwrap();
        // name, NUL, "box2i", NUL, size (4 bytes), then x_min, y_min, x_max, y_max.
        let x_max = at + 11 + 6 + 4 + 8;
        bytes[x_max..x_max + 4].copy_from_slice(b"0000");
        fs::write(&path, &bytes).unwrap();
        let t = std::time::Instant::now();
        let err = format!("{:#}", read_depth_exr(&path).unwrap_err());
        assert!(
            err.contains("claims") && err.contains("s.depth-xmin.exr"),
            "{err}"
        );
        assert!(t.elapsed().as_secs_f64() < 5.0, "{:?}", t.elapsed());
    }
}
