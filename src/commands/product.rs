//! `skybake sun`, `sky`, `ground`, `aerial`: a product's artifact, printed as the service's JSON
//! body or written with `-o` (the EXR the service and bakes store, or a PNG preview).

use std::path::PathBuf;

use skybake_engine::engine::Engine;
use skybake_engine::output::{dome_png, Projection};
use skybake_physics::Error;
use skybake_product::params::RequestParams;
use skybake_product::{artifact, ProductKind, ProductRequest};

use crate::error::Result;
use crate::flags::{DomeOutput, Format, ProjectionArg};
use crate::io::{extension, print_body, request_params, write_file};

/// `skybake sun`: the sun product's JSON body.
pub fn sun(flags: &RequestParams, engine: &Engine) -> Result<()> {
    let req = ProductRequest::from_params(ProductKind::Sun, &request_params(flags.clone())?)?;
    print_body(ProductKind::Sun, &req.compute(engine)?)
}

/// `skybake aerial`: the aerial table's JSON body, or its EXR with `-o FILE.exr`.
pub fn aerial(
    flags: &RequestParams,
    output: Option<&PathBuf>,
    format: Option<Format>,
    engine: &Engine,
) -> Result<()> {
    let req = ProductRequest::from_params(ProductKind::Aerial, &request_params(flags.clone())?)?;
    if let Some(path) = output {
        if extension(path) != "exr" {
            return Err(Error::invalid(
                "output",
                format!("'{}': aerial tables are written as .exr", path.display()),
            )
            .into());
        }
    }
    let image = req.compute(engine)?;
    if let Some(path) = output {
        write_file(path, &skybake_store::encode_exr(&image)?)?;
    }
    if output.is_none() || format == Some(Format::Json) {
        print_body(ProductKind::Aerial, &image)?;
    }
    Ok(())
}

/// `sky`/`ground`: the product's artifact (the EXR the service and bakes store), written with
/// `-o FILE.exr`, previewed with `-o FILE.png`, printed as the service's JSON body.
pub fn run_dome(
    kind: ProductKind,
    flags: &RequestParams,
    out: &DomeOutput,
    engine: &Engine,
) -> Result<()> {
    let ext = out.output.as_deref().map(extension);
    let mut params = flags.clone();
    if ext.as_deref() == Some("png") && out.format != Some(Format::Json) {
        // A PNG alone is RGB-only: the planner may run fewer wavelengths.
        params.format = Some(
            match out.projection {
                ProjectionArg::Fisheye => "png",
                ProjectionArg::Latlong => "png_latlong",
            }
            .into(),
        );
    }
    let req = ProductRequest::from_params(kind, &request_params(params)?)?;
    if let (Some(path), Some(ext)) = (&out.output, &ext) {
        if ext != "png" && ext != "exr" {
            return Err(Error::invalid(
                "output",
                format!("'{}': use a .exr or .png file name", path.display()),
            )
            .into());
        }
    }
    let image = req.compute(engine)?;
    if let (Some(path), Some(ext)) = (&out.output, &ext) {
        if ext == "png" {
            let projection = match out.projection {
                ProjectionArg::Fisheye => Projection::Fisheye,
                ProjectionArg::Latlong => Projection::LatLong,
            };
            let table = artifact::dome_table_of(&image)?;
            write_file(path, &dome_png(&table, projection, out.size)?)?;
        } else {
            write_file(path, &skybake_store::encode_exr(&image)?)?;
        }
    }
    if out.output.is_none() || out.format == Some(Format::Json) {
        print_body(kind, &image)?;
    }
    Ok(())
}
