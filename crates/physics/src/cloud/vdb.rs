//! OpenVDB `.vdb` float grids (Museth 2013, "VDB: high-resolution sparse volumes with dynamic
//! topology", §2–3: a root map of 32³ internal nodes of 16³ internal nodes of 8³ leaves), as
//! Houdini, Blender and production cloud data sets write them.
//!
//! The values are decoded by the `vdb-rs` crate (its Blosc codec is the reference c-blosc). That
//! crate assumes a well-formed file (it panics on transforms it does not know, trusts every size
//! it reads and allocates from it), so [`inspect`] first walks the whole file here, structure
//! only, without decoding or allocating values: it checks the header, selects the grid, refuses
//! what is not a density grid the crate can read, bounds every length by the bytes that are left
//! and every Blosc block by its own header, and measures the active box and the tree's memory.
//! Only then does [`decode`] hand the bytes to `vdb-rs`.
//!
//! Read: file versions 222–224 (OpenVDB 3.0 onwards), `Tree_float_5_4_3` grids stored as float,
//! uncompressed, zip or Blosc, with or without active-mask compression, several grids per
//! file (one selected by name), leaf voxels and active tiles of 8³ and 128³. The transform must
//! be a uniform scale with an optional translation (`UniformScaleMap`,
//! `UniformScaleTranslateMap`, `ScaleTranslateMap` with equal scales): the voxel edge and the
//! position come from it. Inactive voxels are empty (density 0), and the background must be 0.
//! Refused, with the reason: grids saved as half floats (`vdb-rs` 0.6.0 expects a size field
//! where OpenVDB writes nothing for an empty half array, and misreads every tree after its first
//! empty node: measured on the reference library's files), other value types (vectors, integers,
//! doubles, masks), level sets,
//! staggered grids, instanced grids, rotated, sheared, non-uniform or frustum transforms, active
//! root tiles (4096³ constant regions) and multi-buffer trees.

use super::grid::{checked_count, checked_voxel_count, DensityGrid, MAX_VOXELS};
use crate::{Error, Result};
use glam::DVec3;

/// `" BDV"` followed by four zero bytes, little-endian.
const MAGIC: u64 = 0x5644_4220;
/// OpenVDB's `OPENVDB_FILE_VERSION_NODE_MASK_COMPRESSION`: the oldest layout read here.
const MIN_VERSION: u32 = 222;
/// OpenVDB's `OPENVDB_FILE_VERSION_MULTIPASS_IO`: the newest layout (OpenVDB 6–12 write it).
const MAX_VERSION: u32 = 224;
const FLOAT_TREE: &str = "Tree_float_5_4_3";
const HALF_SUFFIX: &str = "_HalfFloat";
const COMPRESS_ZIP: u32 = 0x1;
const COMPRESS_ACTIVE_MASK: u32 = 0x2;
const COMPRESS_BLOSC: u32 = 0x4;
/// Bytes of a Blosc block header (version, flags, type size, sizes).
const BLOSC_HEADER: usize = 16;

/// What [`inspect`] found out about the selected grid, before any value is decoded.
#[derive(Debug, Clone, PartialEq)]
pub struct VdbLayout {
    /// Name of the selected grid.
    pub grid_name: String,
    /// Index of the first active voxel corner (inclusive) and of the last (inclusive).
    pub bbox: ([i32; 3], [i32; 3]),
    /// Voxel counts `[nx, ny, nz]` of the active box.
    pub dims: [usize; 3],
    /// Voxel edge in the file's world units.
    pub voxel_size: f64,
    /// World position of voxel (0, 0, 0)'s centre, file units.
    pub translation: DVec3,
    /// Values stored as half floats.
    pub half: bool,
    /// Leaves, 16³ internal nodes and 32³ internal nodes of the tree.
    pub nodes: [usize; 3],
}

impl VdbLayout {
    /// Minimum corner of the active box, file units: half a voxel below the first voxel centre.
    pub fn origin(&self) -> DVec3 {
        let lo = self.bbox.0;
        (DVec3::new(lo[0] as f64, lo[1] as f64, lo[2] as f64) - 0.5) * self.voxel_size
            + self.translation
    }

    /// Bytes `vdb-rs` allocates for the tree (values and masks of every node; map overhead
    /// included at a generous 64 bytes a node).
    fn tree_bytes(&self) -> usize {
        let [leaves, n4, n5] = self.nodes;
        let half = if self.half { 2 } else { 0 };
        leaves * (512 * 4 + 64 + 64 + 512 * half)
            + n4 * (4096 * 4 + 2 * 512 + 64 + 4096 * half)
            + n5 * (32_768 * 4 + 2 * 4096 + 64 + 32_768 * half)
    }
}

fn corrupt(reason: impl ToString) -> Error {
    Error::invalid(
        "vdb",
        format!("not a readable OpenVDB file: {}", reason.to_string()),
    )
}

/// A bounds-checked little-endian cursor over the file.
struct Cursor<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> Cursor<'a> {
    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8]> {
        let end = self
            .pos
            .checked_add(n)
            .filter(|&e| e <= self.bytes.len())
            .ok_or_else(|| corrupt(format!("the file ends inside {what}")))?;
        let s = &self.bytes[self.pos..end];
        self.pos = end;
        Ok(s)
    }
    fn array<const N: usize>(&mut self, what: &str) -> Result<[u8; N]> {
        let mut a = [0; N];
        a.copy_from_slice(self.take(N, what)?);
        Ok(a)
    }
    fn u8(&mut self, what: &str) -> Result<u8> {
        Ok(self.take(1, what)?[0])
    }
    fn u32(&mut self, what: &str) -> Result<u32> {
        Ok(u32::from_le_bytes(self.array(what)?))
    }
    fn i32(&mut self, what: &str) -> Result<i32> {
        Ok(i32::from_le_bytes(self.array(what)?))
    }
    fn u64(&mut self, what: &str) -> Result<u64> {
        Ok(u64::from_le_bytes(self.array(what)?))
    }
    fn i64(&mut self, what: &str) -> Result<i64> {
        Ok(i64::from_le_bytes(self.array(what)?))
    }
    fn f32(&mut self, what: &str) -> Result<f32> {
        Ok(f32::from_le_bytes(self.array(what)?))
    }
    fn dvec3(&mut self, what: &str) -> Result<DVec3> {
        let mut v = [0.0; 3];
        for c in &mut v {
            *c = f64::from_le_bytes(self.array(what)?);
        }
        Ok(DVec3::from_array(v))
    }
    fn ivec3(&mut self, what: &str) -> Result<[i32; 3]> {
        Ok([self.i32(what)?, self.i32(what)?, self.i32(what)?])
    }
    fn string(&mut self, what: &str) -> Result<String> {
        let n = self.u32(what)? as usize;
        Ok(String::from_utf8_lossy(self.take(n, what)?).into_owned())
    }
    fn seek(&mut self, pos: u64, what: &str) -> Result<()> {
        match usize::try_from(pos) {
            Ok(p) if p <= self.bytes.len() => {
                self.pos = p;
                Ok(())
            }
            _ => Err(corrupt(format!("{what} points past the end of the file"))),
        }
    }
    /// A bit mask of `bits` bits (u64 words), and how many of them are set.
    fn mask(&mut self, bits: usize, what: &str) -> Result<(&'a [u8], usize)> {
        let m = self.take(bits / 8, what)?;
        let ones = m.iter().map(|b| b.count_ones() as usize).sum();
        Ok((m, ones))
    }
}

fn bit(mask: &[u8], i: usize) -> bool {
    mask[i / 8] >> (i % 8) & 1 == 1
}

/// The metadata values this module reads; the others are only skipped.
#[derive(Debug, Clone, PartialEq)]
enum Meta {
    Text(String),
    Bool(bool),
    Other,
}

/// A metadata block: every entry's declared length must match its type's (`vdb-rs` reads the
/// fixed-size types without looking at it).
fn metadata(c: &mut Cursor, what: &str) -> Result<Vec<(String, Meta)>> {
    let count = c.u32(what)?;
    let mut out = Vec::new();
    for _ in 0..count {
        let name = c.string(what)?;
        let kind = c.string(what)?;
        let len = c.u32(what)? as usize;
        let expected = match kind.as_str() {
            "bool" => Some(1),
            "int32" | "float" => Some(4),
            "int64" => Some(8),
            "vec3i" => Some(12),
            _ => None,
        };
        if expected.is_some_and(|e| e != len) {
            return Err(corrupt(format!(
                "{what}: '{name}' of type {kind} declares {len} bytes"
            )));
        }
        let value = c.take(len, what)?;
        let meta = match kind.as_str() {
            "string" => Meta::Text(String::from_utf8_lossy(value).into_owned()),
            "bool" => Meta::Bool(value[0] != 0),
            _ => Meta::Other,
        };
        out.push((name, meta));
    }
    Ok(out)
}

fn meta<'m>(m: &'m [(String, Meta)], name: &str) -> Option<&'m Meta> {
    m.iter().find(|(n, _)| n == name).map(|(_, v)| v)
}

/// A grid descriptor of the file's table.
struct Descriptor {
    name: String,
    kind: String,
    parent: String,
    grid_pos: u64,
    block_pos: u64,
    end_pos: u64,
    compression: u32,
    meta: Vec<(String, Meta)>,
}

/// Names of the grids in `.vdb` bytes (header and descriptors validated; nothing decoded).
pub fn grid_names(bytes: &[u8]) -> Result<Vec<String>> {
    Ok(header(bytes)?.1.into_iter().map(|d| d.name).collect())
}

/// The file version and the grid descriptors.
fn header(bytes: &[u8]) -> Result<(u32, Vec<Descriptor>)> {
    let mut c = Cursor { bytes, pos: 0 };
    if bytes.len() < 8 || c.u64("the header")? != MAGIC {
        return Err(Error::invalid(
            "vdb",
            "not an OpenVDB file (missing the ' BDV' magic)",
        ));
    }
    let version = c.u32("the header")?;
    if !(MIN_VERSION..=MAX_VERSION).contains(&version) {
        return Err(Error::out_of_range(
            "vdb.version",
            version,
            format!(
                "file format {MIN_VERSION}–{MAX_VERSION} (OpenVDB 3 to 12); re-save the file \
                 with a current OpenVDB"
            ),
        ));
    }
    c.take(8, "the header")?; // library version
    if c.u8("the header")? != 1 {
        return Err(corrupt("the header has no grid offsets"));
    }
    c.take(36, "the header")?; // UUID
    metadata(&mut c, "the file metadata")?;
    let count = c.u32("the grid table")?;
    let mut grids: Vec<Descriptor> = Vec::new();
    for _ in 0..count {
        let name = c.string("the grid table")?;
        let kind = c.string("the grid table")?;
        let parent = c.string("the grid table")?;
        let (grid_pos, block_pos, end_pos) = (
            c.u64("the grid table")?,
            c.u64("the grid table")?,
            c.u64("the grid table")?,
        );
        if !(grid_pos <= block_pos && block_pos <= end_pos) {
            return Err(corrupt(format!("grid '{name}' has inconsistent offsets")));
        }
        c.seek(end_pos, "a grid's end")?;
        c.seek(grid_pos, "a grid's offset")?;
        let compression = c.u32("a grid's compression")?;
        if compression & !(COMPRESS_ZIP | COMPRESS_ACTIVE_MASK | COMPRESS_BLOSC) != 0 {
            return Err(corrupt(format!(
                "grid '{name}' has unknown compression flags {compression:#x}"
            )));
        }
        let meta = metadata(&mut c, "a grid's metadata")?;
        if grids.iter().any(|g| g.name == name) {
            return Err(corrupt(format!("two grids are named '{name}'")));
        }
        grids.push(Descriptor {
            name,
            kind,
            parent,
            grid_pos,
            block_pos,
            end_pos,
            compression,
            meta,
        });
        c.seek(end_pos, "a grid's end")?;
    }
    if grids.is_empty() {
        return Err(Error::invalid("vdb", "the file holds no grid"));
    }
    Ok((version, grids))
}

/// The grid `name`, or else `"density"`, or else the file's only grid.
fn select<'d>(grids: &'d [Descriptor], name: Option<&str>) -> Result<&'d Descriptor> {
    let names = || {
        grids
            .iter()
            .map(|g| format!("'{}'", g.name))
            .collect::<Vec<_>>()
            .join(", ")
    };
    match name {
        Some(n) => grids.iter().find(|g| g.name == n).ok_or_else(|| {
            Error::invalid(
                "grid_name",
                format!("the file has no grid '{n}' (its grids: {})", names()),
            )
        }),
        None => match grids.iter().find(|g| g.name == "density") {
            Some(g) => Ok(g),
            None if grids.len() == 1 => Ok(&grids[0]),
            None => Err(Error::invalid(
                "grid_name",
                format!(
                    "the file holds several grids and none is named 'density'; name one of {}",
                    names()
                ),
            )),
        },
    }
}

/// Checks and measures the selected grid of `.vdb` bytes without decoding its values (see the
/// module's documentation for what is read and what is refused). `grid_name` selects the grid
/// [`"density"`, else the only grid]. The active box is refused above [`MAX_VOXELS`] voxels, and
/// the tree `vdb-rs` would build above the same number of f32 values.
pub fn inspect(bytes: &[u8], grid_name: Option<&str>) -> Result<VdbLayout> {
    let (_, grids) = header(bytes)?;
    let g = select(&grids, grid_name)?;
    let name = &g.name;
    let half = match g.kind.strip_suffix(HALF_SUFFIX) {
        Some(base) if base == FLOAT_TREE => true,
        None if g.kind == FLOAT_TREE => false,
        _ => {
            return Err(Error::invalid(
                "grid_name",
                format!(
                    "grid '{name}' is a {} grid; a density must be a float grid ({FLOAT_TREE})",
                    g.kind
                ),
            ))
        }
    };
    if half != (meta(&g.meta, "is_saved_as_half_float") == Some(&Meta::Bool(true))) {
        return Err(corrupt(format!(
            "grid '{name}': its type and its half-float metadata disagree"
        )));
    }
    if half {
        return Err(Error::invalid(
            "vdb.precision",
            format!(
                "grid '{name}' is saved as half floats, which are not read; save it as 32-bit \
                 float (Houdini: VDB 'Save 16-bit float' off; Blender: volume precision 'Full'; \
                 openvdb: saveFloatAsHalf = False)"
            ),
        ));
    }
    if !g.parent.is_empty() {
        return Err(Error::invalid(
            "grid_name",
            format!(
                "grid '{name}' is an instance of grid '{}' (instanced grids are not read); \
                 name '{}' instead",
                g.parent, g.parent
            ),
        ));
    }
    match meta(&g.meta, "class") {
        Some(Meta::Text(class)) if class != "fog volume" && class != "unknown" => {
            return Err(Error::invalid(
                "grid_name",
                format!(
                    "grid '{name}' is a {class} grid; a density must be a fog volume (convert a \
                     level set with Houdini's VDB Convert or openvdb.tools.sdfToFogVolume)"
                ),
            ))
        }
        _ => {}
    }

    let mut c = Cursor { bytes, pos: 0 };
    c.seek(g.grid_pos, "a grid's offset")?;
    c.u32("a grid's compression")?;
    metadata(&mut c, "a grid's metadata")?;
    let map = c.string("the transform")?;
    let (translation, scale, voxel) = match map.as_str() {
        "UniformScaleMap" => {
            let s = c.dvec3("the transform")?;
            let v = c.dvec3("the transform")?;
            c.take(3 * 24, "the transform")?;
            (DVec3::ZERO, s, v)
        }
        "UniformScaleTranslateMap" | "ScaleTranslateMap" => {
            let t = c.dvec3("the transform")?;
            let s = c.dvec3("the transform")?;
            let v = c.dvec3("the transform")?;
            c.take(3 * 24, "the transform")?;
            (t, s, v)
        }
        other => {
            return Err(Error::invalid(
                "vdb.transform",
                format!(
                    "grid '{name}' has a {other}; only axis-aligned grids with cubic voxels \
                     (a uniform scale and a translation) are read: resample the grid onto such \
                     a transform first"
                ),
            ))
        }
    };
    let cubic = voxel.x > 0.0
        && voxel.is_finite()
        && (voxel.y - voxel.x).abs() <= 1e-9 * voxel.x
        && (voxel.z - voxel.x).abs() <= 1e-9 * voxel.x
        && (scale - voxel).abs().max_element() <= 1e-9 * voxel.x
        && translation.is_finite();
    if !cubic {
        return Err(Error::invalid(
            "vdb.transform",
            format!(
                "grid '{name}' has voxels {:?} scaled {:?} and translation {:?}; only cubic, \
                 unmirrored voxels of finite size are read",
                voxel.to_array(),
                scale.to_array(),
                translation.to_array()
            ),
        ));
    }

    let walk = Walk {
        compression: g.compression,
        elem: if half { 2 } else { 4 },
        name,
    };
    if c.u32("the tree")? != 1 {
        return Err(corrupt(format!(
            "grid '{name}' is a multi-buffer tree (not read)"
        )));
    }
    let background = c.f32("the tree")?;
    if background != 0.0 {
        return Err(Error::invalid(
            "vdb.background",
            format!(
                "grid '{name}' has background {background}; a density grid's background (its \
                 value outside the active voxels) must be 0"
            ),
        ));
    }
    let tiles = c.u32("the tree")?;
    let children = c.u32("the tree")?;
    let mut bbox = Bbox::default();
    for _ in 0..tiles {
        c.ivec3("a root tile")?;
        c.f32("a root tile")?;
        if c.u8("a root tile")? != 0 {
            return Err(Error::invalid(
                "vdb",
                format!(
                    "grid '{name}' has an active root tile (a 4096³ constant region), which is \
                     not read"
                ),
            ));
        }
    }
    // Topology (Museth 2013, §3): each 32³ node's masks and tile values, then its 16³ children's,
    // then each child's leaves' value masks.
    let mut leaf_origins = Vec::new();
    let mut nodes = [0usize; 3];
    for _ in 0..children {
        let o5 = c.ivec3("the tree")?;
        nodes[2] += 1;
        let (child5, _) = c.mask(32_768, "a 32³ node")?;
        let (value5, ones5) = c.mask(32_768, "a 32³ node")?;
        walk.values(&mut c, 32_768, ones5, "a 32³ node")?;
        for i in 0..32_768 {
            let o4 = child_origin(o5, i, 5, 7);
            if bit(child5, i) {
                nodes[1] += 1;
                let (child4, _) = c.mask(4096, "a 16³ node")?;
                let (value4, ones4) = c.mask(4096, "a 16³ node")?;
                walk.values(&mut c, 4096, ones4, "a 16³ node")?;
                for j in 0..4096 {
                    let o3 = child_origin(o4, j, 4, 3);
                    if bit(child4, j) {
                        nodes[0] += 1;
                        let (mask, _) = c.mask(512, "a leaf")?;
                        for k in (0..512).filter(|&k| bit(mask, k)) {
                            bbox.add(child_origin(o3, k, 3, 0), 1);
                        }
                        leaf_origins.push(o3);
                    } else if bit(value4, j) {
                        bbox.add(o3, 8);
                    }
                }
            } else if bit(value5, i) {
                bbox.add(o4, 128);
            }
        }
        // An estimate of the tree's memory grows with every node: stop a hostile file early.
        let partial = VdbLayout {
            grid_name: String::new(),
            bbox: ([0; 3], [0; 3]),
            dims: [1; 3],
            voxel_size: 1.0,
            translation: DVec3::ZERO,
            half,
            nodes,
        };
        check_tree(&partial, name)?;
    }
    // Leaf buffers: each leaf's value mask again, then its 512 values.
    c.seek(g.block_pos, "a grid's data offset")?;
    for _ in &leaf_origins {
        let (_, ones) = c.mask(512, "a leaf's values")?;
        walk.values(&mut c, 512, ones, "a leaf's values")?;
    }
    if c.pos as u64 > g.end_pos {
        return Err(corrupt(format!("grid '{name}' runs past its end offset")));
    }
    let Some((lo, hi)) = bbox.get() else {
        return Err(Error::invalid(
            "grid_name",
            format!("grid '{name}' has no active voxel"),
        ));
    };
    let extent = |a: usize| (hi[a] as i64 - lo[a] as i64 + 1) as usize;
    let dims = [extent(0), extent(1), extent(2)];
    checked_count(dims, MAX_VOXELS, "voxels")?;
    let layout = VdbLayout {
        grid_name: name.clone(),
        bbox: (lo, hi),
        dims,
        voxel_size: voxel.x,
        translation,
        half,
        nodes,
    };
    check_tree(&layout, name)?;
    Ok(layout)
}

fn check_tree(layout: &VdbLayout, name: &str) -> Result<()> {
    let limit = MAX_VOXELS * 4;
    let bytes = layout.tree_bytes();
    if bytes > limit {
        return Err(Error::too_large(
            "vdb",
            format!("grid '{name}''s tree needs {bytes} bytes"),
            format!("{limit} bytes"),
        ));
    }
    Ok(())
}

/// Origin of child `i` of a node at `origin` with `log2` children a side, each `2^child_log2`
/// voxels wide (OpenVDB's offset order: z fastest).
fn child_origin(origin: [i32; 3], i: usize, log2: u32, child_log2: u32) -> [i32; 3] {
    let m = (1usize << log2) - 1;
    let (x, y, z) = (i >> (2 * log2), (i >> log2) & m, i & m);
    [
        origin[0].wrapping_add((x << child_log2) as i32),
        origin[1].wrapping_add((y << child_log2) as i32),
        origin[2].wrapping_add((z << child_log2) as i32),
    ]
}

/// The active box, grown by cubes of `size` voxels at `origin`.
#[derive(Default)]
struct Bbox(Option<([i32; 3], [i32; 3])>);

impl Bbox {
    fn add(&mut self, origin: [i32; 3], size: i32) {
        let hi = origin.map(|o| o.saturating_add(size - 1));
        self.0 = Some(match self.0 {
            None => (origin, hi),
            Some((l, h)) => (
                [0, 1, 2].map(|a| l[a].min(origin[a])),
                [0, 1, 2].map(|a| h[a].max(hi[a])),
            ),
        });
    }
    fn get(&self) -> Option<([i32; 3], [i32; 3])> {
        self.0
    }
}

/// How a grid's value arrays are stored.
struct Walk<'n> {
    compression: u32,
    /// Bytes per stored value (2 for half floats).
    elem: usize,
    name: &'n str,
}

impl Walk<'_> {
    /// Skips one compressed value array of `count` values of which `active` are active
    /// (OpenVDB's `readCompressedValues`), checking every size against the file and each Blosc
    /// block's header against the size it must decode to.
    fn values(&self, c: &mut Cursor, count: usize, active: usize, what: &str) -> Result<()> {
        let flag = c.u8(what)?;
        if flag > 6 {
            return Err(corrupt(format!(
                "grid '{}': {what} has mask flag {flag}",
                self.name
            )));
        }
        if matches!(flag, 2 | 4 | 5) {
            c.take(4, what)?; // inactive value, stored as float even in half grids
        }
        if flag == 5 {
            c.take(4, what)?;
        }
        if matches!(flag, 3..=5) {
            c.take(count / 8, what)?; // selection mask
        }
        let n = if self.compression & COMPRESS_ACTIVE_MASK != 0 && flag != 6 {
            active
        } else {
            count
        };
        let raw = n * self.elem;
        if self.elem == 2 && n == 0 {
            return Ok(()); // OpenVDB writes nothing for an empty half array
        }
        if self.compression & (COMPRESS_BLOSC | COMPRESS_ZIP) == 0 {
            c.take(raw, what)?;
            return Ok(());
        }
        let size = c.i64(what)?;
        if size <= 0 {
            if size.unsigned_abs() != raw as u64 {
                return Err(corrupt(format!(
                    "grid '{}': {what} stores {} bytes for {n} values",
                    self.name,
                    size.unsigned_abs()
                )));
            }
            c.take(raw, what)?;
            return Ok(());
        }
        let block = c.take(size as usize, what)?;
        if self.compression & COMPRESS_BLOSC != 0 && n > 0 {
            let field = |at: usize| {
                u32::from_le_bytes([block[at], block[at + 1], block[at + 2], block[at + 3]])
                    as usize
            };
            if block.len() < BLOSC_HEADER || field(4) != raw || field(12) != block.len() {
                return Err(corrupt(format!(
                    "grid '{}': {what} has a Blosc block that does not match its size",
                    self.name
                )));
            }
        }
        Ok(())
    }
}

/// The selected grid of `.vdb` bytes as a density grid over its active box, the file's world
/// units multiplied by `unit_m` (metres per unit). `layout` comes from [`inspect`] on the same
/// bytes. Voxel (i, j, k) of the file is centred at `(i, j, k)·voxel + translation`.
pub fn decode(bytes: &[u8], layout: &VdbLayout, unit_m: f64) -> Result<DensityGrid> {
    let name = &layout.grid_name;
    let count = checked_voxel_count(layout.dims)?;
    let mut reader =
        vdb_rs::VdbReader::new(std::io::Cursor::new(bytes)).map_err(|e| corrupt(format!("{e}")))?;
    let grid = reader
        .read_grid::<f32>(name)
        .map_err(|e| corrupt(format!("grid '{name}': {e}")))?;
    let mut data = vec![0.0f32; count];
    let [nx, ny, nz] = layout.dims;
    let lo = layout.bbox.0;
    for (at, value, level) in grid.iter() {
        if !(value.is_finite() && value >= 0.0) {
            return Err(Error::invalid(
                "vdb",
                format!(
                    "grid '{name}' holds the density {value} at index {:?}; densities must be \
                     finite and >= 0",
                    [at.x, at.y, at.z]
                ),
            ));
        }
        let size = match level {
            vdb_rs::VdbLevel::Voxel => 1,
            vdb_rs::VdbLevel::Node3 => 8,
            vdb_rs::VdbLevel::Node4 => 128,
        };
        // Integer index coordinates, exact in f32 up to 2^24 (the box is at most 512³ voxels).
        let start = [
            at.x as i64 - lo[0] as i64,
            at.y as i64 - lo[1] as i64,
            at.z as i64 - lo[2] as i64,
        ];
        let inside = |a: usize, n: usize| start[a] >= 0 && start[a] + size as i64 <= n as i64;
        if !(inside(0, nx) && inside(1, ny) && inside(2, nz)) {
            return Err(corrupt(format!(
                "grid '{name}': a value at {:?} lies outside the walked tree",
                [at.x, at.y, at.z]
            )));
        }
        let [x0, y0, z0] = start.map(|s| s as usize);
        for z in z0..z0 + size {
            for y in y0..y0 + size {
                let row = (z * ny + y) * nx;
                data[row + x0..row + x0 + size].fill(value);
            }
        }
    }
    DensityGrid::from_data(
        layout.dims,
        layout.voxel_size * unit_m,
        layout.origin() * unit_m,
        data,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn child_origins_follow_openvdb_order() {
        // z fastest, then y, then x; a 16³ node's children are 8 voxels wide.
        assert_eq!(child_origin([0, 0, 0], 1, 4, 3), [0, 0, 8]);
        assert_eq!(child_origin([0, 0, 0], 16, 4, 3), [0, 8, 0]);
        assert_eq!(child_origin([0, 0, 0], 256, 4, 3), [8, 0, 0]);
        assert_eq!(
            child_origin([-4096, 0, 4096], 32_767, 5, 7),
            [-128, 3968, 8064]
        );
        assert_eq!(child_origin([8, 16, 24], 511, 3, 0), [15, 23, 31]);
    }

    #[test]
    fn refuses_what_is_not_vdb() {
        for bytes in [&b""[..], b"\x93NUMPY\x01\x00", &[0u8; 64]] {
            let e = inspect(bytes, None).unwrap_err();
            assert!(e.to_string().contains("vdb"), "{e}");
        }
    }
}
