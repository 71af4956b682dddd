# syntax=docker/dockerfile:1
# skybake service image: build the release binary, ship only it and config/ on a slim base.
#
#   docker build -t skybake .
#   docker run --rm -p 8080:8080 -v skybake-cache:/var/cache/skybake skybake

# ---- build -------------------------------------------------------------------------------------
FROM rust:1.95-bookworm AS build
WORKDIR /src
# The workspace (every member's manifest and sources, and the test targets the root manifest
# names) and what the crates embed at compile time: config/ and data/ tables, the measured
# report (report/report.json), the viewer (web/), the harness's font (assets/).
COPY Cargo.toml Cargo.lock ./
COPY crates ./crates
COPY src ./src
COPY tests ./tests
COPY config ./config
COPY data ./data
COPY report ./report
COPY web ./web
COPY assets ./assets
# With the S3-compatible bucket backend (`--features s3`): replicas and sharded bakes share a
# bucket (docs/deploy.md).
RUN cargo build --release --locked -p skybake --bin skybake --features s3 \
    && strip target/release/skybake

# ---- runtime -----------------------------------------------------------------------------------
FROM debian:bookworm-slim
# CA certificates: a shared cache bucket (SKYBAKE_CACHE_URL=s3://…) is reached over HTTPS.
RUN apt-get update \
    && apt-get install -y --no-install-recommends ca-certificates \
    && rm -rf /var/lib/apt/lists/*
RUN groupadd --system --gid 10001 skybake \
    && useradd --system --uid 10001 --gid 10001 --no-create-home --home-dir /nonexistent skybake \
    && mkdir -p /var/cache/skybake \
    && chown skybake:skybake /var/cache/skybake
COPY --from=build /src/target/release/skybake /usr/local/bin/skybake
COPY config /etc/skybake/config
ENV SKYBAKE_BIND=0.0.0.0:8080 \
    SKYBAKE_CACHE_DIR=/var/cache/skybake \
    SKYBAKE_LOG=info
VOLUME ["/var/cache/skybake"]
USER 10001:10001
EXPOSE 8080
# No curl in the slim image: the binary's own client asks GET /healthz on the configured address.
HEALTHCHECK --interval=30s --timeout=5s --start-period=10s --retries=3 \
    CMD ["/usr/local/bin/skybake", "healthcheck"]
STOPSIGNAL SIGTERM
ENTRYPOINT ["/usr/local/bin/skybake"]
CMD ["serve", "--config", "/etc/skybake/config/default.toml"]
