//! `skybake plan`: the stages a request would run and those left out, without computing (the
//! `POST /v1/plan` answer).

use std::path::Path;

use skybake_engine::engine::{Engine, ENGINE_VERSION};
use skybake_physics::cloud::scene::{MAX_GRID_FILE_BYTES, MAX_SCENE_FILE_BYTES};
use skybake_physics::Error;
use skybake_product::frame::FrameRequest;
use skybake_product::{ProductKind, ProductRequest};
use skybake_render::Method;

use crate::error::Result;
use crate::flags::PlanArgs;
use crate::io::{print_json, read_limited, request_params};

/// Plans `args.product`: a frame (with `--scene`) or an atmosphere product.
pub fn plan(args: &PlanArgs, engine: impl FnOnce() -> Result<Engine>) -> Result<()> {
    if args.product == "frame" {
        return plan_frame(args, &engine()?);
    }
    if args.scene.is_some() {
        return Err(Error::invalid("scene", "only for plan frame").into());
    }
    if args.rgb_only {
        return Err(Error::invalid("rgb_only", "only for plan frame").into());
    }
    let kind = ProductKind::parse(&args.product)?;
    let req = ProductRequest::from_params(kind, &request_params(args.flags.params.clone())?)?;
    print_json(&serde_json::json!({
        "product": kind.name(),
        "cache_key": req.cache_key(),
        "engine_version": ENGINE_VERSION,
        "plan": req.plan()?,
        "work_cells": req.work_cells(),
    }))
}

fn plan_frame(args: &PlanArgs, engine: &Engine) -> Result<()> {
    let scene = args
        .scene
        .as_deref()
        .ok_or_else(|| Error::invalid("scene", "plan frame needs --scene SCENE.json"))?;
    let method = match args.flags.params.method.as_deref() {
        Some(m) => Method::parse(m)?,
        None => Method::Fast,
    };
    let text = read_limited(scene, "scene", MAX_SCENE_FILE_BYTES)?;
    let request = FrameRequest::parse(&text, method)?
        .with_max_rel_error(args.flags.params.max_rel_error.as_deref())?
        .with_rgb_only(args.rgb_only);
    let dir = scene.parent().unwrap_or(Path::new("."));
    let loader = |name: &str| read_limited(&dir.join(name), "path", MAX_GRID_FILE_BYTES);
    print_json(&serde_json::json!({
        "product": "frame",
        "cache_key": request.cache_key(),
        "engine_version": ENGINE_VERSION,
        "method": method,
        "plan": request.plan(engine, &loader)?,
    }))
}
