//! The real-time texture bundle as a request: which parameters it takes (the atmosphere's, not
//! the observer's or the sun's), its canonical form and cache key, its computation on the
//! engine's shared tables (so the precise table is the one every product uses, stored and
//! reused as theirs), and its files (OpenEXR textures + `manifest.json`, through the store).

use std::sync::{Arc, Mutex, OnceLock};

use rayon::prelude::*;
use serde_json::{json, Value};
use skybake_engine::engine::{Engine, ENGINE_VERSION};
use skybake_engine::spec::CommonSpec;
pub use skybake_lut::manifest::MANIFEST_FILE;
use skybake_lut::manifest::{
    self, IRRADIANCE_FILE, SCATTERING_FILE, SINGLE_MIE_FILE, TRANSMITTANCE_FILE,
};
use skybake_lut::skyview;
use skybake_lut::{Bundle, Channels, Sample, SkyViewBundle, Texture};
use skybake_physics::atmosphere::shared::SharedTables;
use skybake_physics::atmosphere::sky::MsMethod;
use skybake_physics::key::cache_key;
use skybake_store::texture::{encode_texture_exr, TextureFile, TextureImage};

use crate::params::{common_spec, RequestParams, PARAMETERS};
use crate::{Error, Result};

/// Parameters of the table that describe the observer, the sun or the response, which a bundle
/// (valid for every observer and sun) does not take.
const NOT_FOR_LUT: &[&str] = &[
    "sun_elevation_deg",
    "latitude_deg",
    "longitude_deg",
    "time",
    "observer_altitude_m",
    "method",
    "max_rel_error",
    "elevation_count",
    "azimuth_count",
    "distance_count",
    "max_distance_m",
    "probe",
    "format",
];

/// Whether the bundle takes parameter `name` of the parameter table (the atmosphere, haze,
/// ground albedo, wavelengths and quality rows).
pub fn takes(name: &str) -> bool {
    PARAMETERS.iter().any(|p| p.name == name) && !NOT_FOR_LUT.contains(&name)
}

/// The bundle layouts (`--layout`, `layout=`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Layout {
    /// Bruneton 2017's textures and parameterisation (the default).
    Bruneton2017,
    /// skybake's sky-view layout ([`skybake_lut::skyview`], docs/lut.md).
    SkyView,
}

/// The layouts' names, as `--layout` takes them.
pub const LAYOUTS: &[&str] = &["bruneton2017", skybake_lut::skyview::LAYOUT];

impl Layout {
    /// The layout named `name`; an unknown name is out of range, naming `layout` and the choices
    /// (HTTP 400, as every bad value).
    pub fn parse(name: &str) -> Result<Self> {
        match name {
            "bruneton2017" => Ok(Self::Bruneton2017),
            n if n == skybake_lut::skyview::LAYOUT => Ok(Self::SkyView),
            other => Err(Error::out_of_range("layout", other, LAYOUTS.join(", "))),
        }
    }
}

/// One file of a bundle: its name and its bytes.
pub type BundleFile = (&'static str, Vec<u8>);

/// A bundle request: the atmosphere's spec, and RGB (no `wavelengths`) or spectral form.
#[derive(Debug, Clone)]
pub struct LutRequest {
    pub spec: CommonSpec,
    pub channels: Channels,
    pub layout: Layout,
}

impl LutRequest {
    /// From request parameters (CLI flags, query): refuses the observer's and the sun's.
    pub fn from_params(p: &RequestParams) -> Result<Self> {
        if let Some(name) = NOT_FOR_LUT.iter().find(|n| p.get(n).is_some()) {
            return Err(Error::invalid(
                name,
                "a texture bundle holds every observer, view and sun; it takes the atmosphere's parameters only (atmosphere, visibility_km, aerosol_type, boundary_layer_top_m, ground_albedo, wavelengths, quality) and layout",
            ));
        }
        let layout = match p.layout.as_deref() {
            Some(name) => Layout::parse(name)?,
            None => Layout::Bruneton2017,
        };
        let mut p = p.clone();
        let channels = if p.wavelengths.is_some() {
            Channels::Spectral
        } else {
            let nm: Vec<String> = skybake_lut::build::RGB_WAVELENGTHS_NM
                .iter()
                .map(|w| w.to_string())
                .collect();
            p.wavelengths = Some(nm.join(","));
            Channels::Rgb
        };
        let mut spec = common_spec(&p, -90.0)?;
        spec.method = MsMethod::Precise;
        Ok(Self {
            spec,
            channels,
            layout,
        })
    }

    /// This request in another layout.
    pub fn with_layout(self, layout: Layout) -> Self {
        Self { layout, ..self }
    }

    /// The canonical request (the manifest's `request`, the cache key's text).
    pub fn canonical(&self) -> Value {
        if self.layout == Layout::SkyView {
            return json!({
                "product": "lut",
                "layout": skybake_lut::skyview::LAYOUT,
                "form": match self.channels { Channels::Rgb => "rgb", Channels::Spectral => "spectral" },
                "atmosphere": self.spec.atmosphere,
                "wavelengths_nm": self.spec.wavelengths_nm,
                "ground_albedo": self.spec.ground_albedo,
                "quality": self.spec.quality,
                "bundle_version": skybake_lut::skyview::SKYVIEW_VERSION,
            });
        }
        json!({
            "product": "lut",
            "form": match self.channels { Channels::Rgb => "rgb", Channels::Spectral => "spectral" },
            "atmosphere": self.spec.atmosphere,
            "wavelengths_nm": self.spec.wavelengths_nm,
            "ground_albedo": self.spec.ground_albedo,
            "quality": self.spec.quality,
            "bundle_version": manifest::BUNDLE_VERSION,
        })
    }

    pub fn cache_key(&self) -> String {
        cache_key(&self.canonical().to_string(), &Self::version())
    }

    /// The engine's version and the revision of the bundles' texel values
    /// ([`skybake_lut::TEXEL_REVISION`]): a cached bundle computed otherwise is not reused.
    fn version() -> String {
        format!("{ENGINE_VERSION}+texels-{}", skybake_lut::TEXEL_REVISION)
    }

    /// The cache key of the bundle's file `name` (a texture; the manifest's is [`Self::cache_key`]).
    pub fn file_key(&self, name: &str) -> String {
        cache_key(
            &json!({"bundle": self.canonical(), "file": name}).to_string(),
            &Self::version(),
        )
    }

    /// Computes Bruneton's layout on the engine's shared tables (built, or loaded from its table
    /// store, as for any product of this atmosphere and wavelengths).
    pub fn compute(&self, engine: &Engine) -> Result<Bundle> {
        self.compute_unless(engine, &|| false)
    }

    /// [`Self::compute`], stopped with [`Error::Cancelled`] inside the tables' build or at the
    /// next texture row once `cancelled` returns true.
    pub fn compute_unless(
        &self,
        engine: &Engine,
        cancelled: &(dyn Fn() -> bool + Sync),
    ) -> Result<Bundle> {
        self.build_with(engine, cancelled, skybake_lut::build)
    }

    /// Computes the `skyview` layout on the engine's shared tables.
    pub fn compute_skyview(&self, engine: &Engine) -> Result<SkyViewBundle> {
        self.build_with(engine, &|| false, skybake_lut::build_skyview)
    }

    /// Runs a layout's builder on the engine's shared tables, stopped with [`Error::Cancelled`]
    /// inside the tables' build or at the builder's next row once `cancelled` returns true.
    fn build_with<B>(
        &self,
        engine: &Engine,
        cancelled: &(dyn Fn() -> bool + Sync),
        build: impl FnOnce(
            &SharedTables,
            Channels,
            usize,
            &(dyn Fn() -> bool + Sync),
        ) -> skybake_lut::Result<B>,
    ) -> Result<B> {
        let shared = engine.shared_unless(&self.spec, cancelled)?;
        build(
            &shared,
            self.channels.clone(),
            self.spec.quality.steps(),
            cancelled,
        )
    }

    /// Computes the bundle in its layout and encodes its files: (name, bytes), the manifest
    /// last, and the stages' times (ms: precise table, transmittance, scattering or sky view,
    /// irradiance).
    pub fn compute_files_unless(
        &self,
        engine: &Engine,
        cancelled: &(dyn Fn() -> bool + Sync),
    ) -> Result<(Vec<BundleFile>, [f64; 4])> {
        match self.layout {
            Layout::Bruneton2017 => {
                let bundle = self.compute_unless(engine, cancelled)?;
                Ok((self.files(&bundle)?, bundle.timing_ms))
            }
            Layout::SkyView => {
                // The Rayleigh-like and Mie files, nine tenths of the bundle's bytes, compressed
                // altitude node by node while the build's last rows are computed.
                let encoder = OnceLock::new();
                let bundle = self.build_with(engine, cancelled, |shared, channels, steps, c| {
                    let names = channel_names(&channels, &shared.medium.wavelengths_nm);
                    let encoder = encoder.get_or_init(|| SliceEncoder::new(&names));
                    skybake_lut::build_skyview_into(shared, channels, steps, c, &|k, r, m| {
                        encoder.altitude(k, [r, m])
                    })
                })?;
                let names = channel_names(&bundle.channels, &bundle.wavelengths_nm);
                let streamed = encoder
                    .into_inner()
                    .filter(|e| e.names == names)
                    .and_then(SliceEncoder::finish);
                Ok((
                    self.skyview_files_with(&bundle, streamed)?,
                    bundle.timing_ms,
                ))
            }
        }
    }

    /// The `skyview` bundle's files: (name, bytes), the manifest last.
    pub fn skyview_files(&self, bundle: &SkyViewBundle) -> Result<Vec<(&'static str, Vec<u8>)>> {
        self.skyview_files_with(bundle, None)
    }

    /// [`Self::skyview_files`], the Rayleigh-like and Mie files' ZIP blocks already compressed
    /// where `streamed` holds them ([`SliceEncoder::finish`]).
    fn skyview_files_with(
        &self,
        bundle: &SkyViewBundle,
        streamed: Option<[(TextureFile, Vec<Vec<u8>>); 2]>,
    ) -> Result<Vec<(&'static str, Vec<u8>)>> {
        let names = channel_names(&bundle.channels, &bundle.wavelengths_nm);
        let mut scale_names: Vec<String> = names.iter().map(|n| format!("rayleigh.{n}")).collect();
        scale_names.extend(names.iter().map(|n| format!("mie.{n}")));
        let streamed = streamed.filter(|_| {
            [&bundle.rayleigh, &bundle.mie].iter().all(|t| {
                (t.width, t.height, t.depth, t.channels, t.sample)
                    == (
                        skyview::N_AZ,
                        skyview::N_VIEW,
                        skyview::N_ALT * skyview::N_SUN,
                        names.len(),
                        Sample::Half,
                    )
            })
        });
        let (rayleigh, mie) = match streamed {
            Some([r, m]) => (Some(r), Some(m)),
            None => (None, None),
        };
        // Encoded side by side (the largest first), each file's bytes as encoded alone.
        let textures = vec![
            (skyview::RAYLEIGH_FILE, &bundle.rayleigh, &names, rayleigh),
            (skyview::MIE_FILE, &bundle.mie, &names, mie),
            (TRANSMITTANCE_FILE, &bundle.transmittance, &names, None),
            (skyview::SCALE_FILE, &bundle.scale, &scale_names, None),
            (skyview::IRRADIANCE_FILE, &bundle.irradiance, &names, None),
        ];
        let mut encoded: Vec<(&'static str, Vec<u8>)> = textures
            .into_par_iter()
            .map(|(name, t, n, blocks)| {
                let bytes = match blocks {
                    Some((file, blocks)) => {
                        file.write(blocks).map_err(|e| Error::internal("lut", e))?
                    }
                    None => encode(t, n)?,
                };
                Ok((name, bytes))
            })
            .collect::<Result<_>>()?;
        // The files in the bundle's order: transmittance, rayleigh, mie, scale, irradiance.
        encoded.swap(0, 2);
        encoded.swap(1, 2);
        let mut files = encoded;
        let m = skyview::manifest(
            bundle,
            &names,
            &scale_names,
            self.canonical(),
            ENGINE_VERSION,
        );
        let text = serde_json::to_string_pretty(&m).map_err(|e| Error::internal("lut", e))?;
        files.push((MANIFEST_FILE, text.into_bytes()));
        Ok(files)
    }

    /// The bundle's files: (name, bytes), the manifest last.
    pub fn files(&self, bundle: &Bundle) -> Result<Vec<(&'static str, Vec<u8>)>> {
        let names: Vec<String> = match bundle.channels {
            Channels::Rgb => vec!["R".into(), "G".into(), "B".into(), "A".into()],
            Channels::Spectral => bundle
                .wavelengths_nm
                .iter()
                .map(|w| skybake_physics::image::layout::spectral_channel_name("L", *w))
                .collect(),
        };
        let encode = |t: &Texture| -> Result<Vec<u8>> {
            let channels = (0..t.channels)
                .map(|c| (names[c].as_str(), t.plane(c)))
                .collect();
            encode_texture_exr(TextureImage {
                width: t.width,
                height: t.height * t.depth,
                channels,
                half: t.sample == Sample::Half,
            })
            .map_err(|e| Error::internal("lut", e))
        };
        let mut files = vec![
            (TRANSMITTANCE_FILE, encode(&bundle.transmittance)?),
            (SCATTERING_FILE, encode(&bundle.scattering)?),
        ];
        if let Some(mie) = &bundle.single_mie {
            files.push((SINGLE_MIE_FILE, encode(mie)?));
        }
        files.push((IRRADIANCE_FILE, encode(&bundle.irradiance)?));
        let m = manifest::manifest(bundle, self.canonical(), ENGINE_VERSION);
        let text = serde_json::to_string_pretty(&m).map_err(|e| Error::internal("lut", e))?;
        files.push((MANIFEST_FILE, text.into_bytes()));
        Ok(files)
    }
}

/// The channel names of a bundle's textures: R, G, B, or the spectral layout's `L.<nm>`.
fn channel_names(channels: &Channels, wavelengths_nm: &[f64]) -> Vec<String> {
    match channels {
        Channels::Rgb => vec!["R".into(), "G".into(), "B".into()],
        Channels::Spectral => wavelengths_nm
            .iter()
            .map(|w| skybake_physics::image::layout::spectral_channel_name("L", *w))
            .collect(),
    }
}

/// A texture as a ZIP-compressed OpenEXR file, its channels named `names`.
fn encode(t: &Texture, names: &[String]) -> Result<Vec<u8>> {
    let channels = (0..t.channels)
        .map(|c| (names[c].as_str(), t.plane(c)))
        .collect();
    encode_texture_exr(TextureImage {
        width: t.width,
        height: t.height * t.depth,
        channels,
        half: t.sample == Sample::Half,
    })
    .map_err(|e| Error::internal("lut", e))
}

/// An altitude node's slices of the Rayleigh-like and the Mie texture.
type NodeSlices = Arc<[Vec<f32>; 2]>;

/// The `skyview` bundle's Rayleigh-like and Mie files ([`skyview::RAYLEIGH_FILE`],
/// [`skyview::MIE_FILE`]) compressed while the bundle is built: each ZIP block as soon as the
/// altitude nodes whose slices it covers are final (`skybake_lut::build_skyview_into`), the
/// bytes of the files encoded from the finished textures.
struct SliceEncoder {
    /// The textures' channel names (the bundle's, [`channel_names`]).
    names: Vec<String>,
    files: [TextureFile; 2],
    /// Per altitude node, its two textures' slices once final.
    nodes: Mutex<Vec<Option<NodeSlices>>>,
    /// Per file, its blocks once compressed.
    blocks: Mutex<[Vec<Option<Vec<u8>>>; 2]>,
}

impl SliceEncoder {
    /// Lines of the textures per altitude node (its N_SUN slices of N_VIEW rows).
    const NODE_LINES: usize = skyview::N_SUN * skyview::N_VIEW;

    fn new(names: &[String]) -> Self {
        let refs: Vec<&str> = names.iter().map(String::as_str).collect();
        let height = skyview::N_ALT * Self::NODE_LINES;
        let file = || TextureFile::new(skyview::N_AZ, height, &refs, true);
        let files = [file(), file()];
        let count = files[0].blocks();
        Self {
            names: names.to_vec(),
            files,
            nodes: Mutex::new(vec![None; skyview::N_ALT]),
            blocks: Mutex::new([vec![None; count], vec![None; count]]),
        }
    }

    /// Altitude node `k`'s slices ([`skyview::AltitudeSink`]): keeps them, then compresses
    /// every block of both files that they complete (on the cores).
    fn altitude(&self, k: usize, slices: [&[f32]; 2]) {
        let n_c = self.names.len();
        let node_of = |y: usize| y / Self::NODE_LINES;
        let file = &self.files[0];
        let (ready, nodes) = {
            let Ok(mut nodes) = self.nodes.lock() else {
                return;
            };
            nodes[k] = Some(Arc::new(slices.map(<[f32]>::to_vec)));
            let first = k * Self::NODE_LINES / file.block_lines(0).len();
            let ready: Vec<usize> = (first..file.blocks())
                .take_while(|&b| node_of(file.block_lines(b).start) <= k)
                .filter(|&b| {
                    let lines = file.block_lines(b);
                    (node_of(lines.start)..=node_of(lines.end - 1)).all(|n| nodes[n].is_some())
                })
                .collect();
            (ready, nodes.clone())
        };
        let value = |part: usize| {
            let nodes = &nodes;
            move |c: usize, y: usize, x: usize| match &nodes[node_of(y)] {
                Some(node) => node[part][((y % Self::NODE_LINES) * skyview::N_AZ + x) * n_c + c],
                None => f32::NAN,
            }
        };
        let compressed: Vec<(usize, usize, Vec<u8>)> = ready
            .par_iter()
            .flat_map_iter(|&b| (0..2).map(move |part| (part, b)))
            .map(|(part, b)| (part, b, self.files[part].zip_block(b, value(part))))
            .collect();
        if let Ok(mut blocks) = self.blocks.lock() {
            for (part, b, bytes) in compressed {
                blocks[part][b] = Some(bytes);
            }
        }
    }

    /// The two files' layouts and blocks, if every block was compressed.
    fn finish(self) -> Option<[(TextureFile, Vec<Vec<u8>>); 2]> {
        let [r, m] = self.blocks.into_inner().ok()?;
        let all = |b: Vec<Option<Vec<u8>>>| b.into_iter().collect::<Option<Vec<_>>>();
        let [fr, fm] = self.files;
        Some([(fr, all(r)?), (fm, all(m)?)])
    }
}
