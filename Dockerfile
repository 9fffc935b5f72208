# ilqr-service container image.
#
#   docker build -t ilqr-service .
#   docker run --rm -p 8080:8080 -p 50051:50051 ilqr-service   # HTTP, gRPC
#
# Four stages:
#   chef     - Rust toolchain + cargo-chef, shared by the next two stages.
#   planner  - reduces the workspace to a "recipe" (manifests + lockfile only).
#   builder  - compiles the dependencies from the recipe (cached layer), then
#              the workspace's own code.
#   runtime  - distroless image holding only the binary.
#
# Why cargo-chef: Docker caches a layer until one of its inputs changes. A
# plain `COPY . . && cargo build` recompiles every crate from crates.io on any
# source edit. The recipe only changes when Cargo.toml/Cargo.lock change, so the
# expensive `cargo chef cook` layer is reused across ordinary code changes and
# only the workspace crates are rebuilt.

# ---------------------------------------------------------------------------
# Toolchain pinned to the same minor version the project is developed with, on
# Debian 12 (bookworm) so the glibc we link against matches the runtime image
# (distroless cc-debian12). Mixing Debian releases risks "GLIBC_x.y not found".
FROM rust:1.95-slim-bookworm AS chef
# Pinned and --locked so the planner/cook logic (and hence the cache keys) do
# not change under us between builds.
RUN cargo install cargo-chef --locked --version 0.1.78
WORKDIR /app

# ---------------------------------------------------------------------------
FROM chef AS planner
# .dockerignore is an allow-list, so this copies only what the build needs.
COPY . .
RUN cargo chef prepare --recipe-path recipe.json

# ---------------------------------------------------------------------------
FROM chef AS builder
COPY --from=planner /app/recipe.json recipe.json
# Build only the dependency graph. Same profile (--release), lockfile policy
# (--locked) and target selection as the real build below; if they differed,
# cargo would consider the cooked artefacts stale and rebuild everything.
RUN cargo chef cook --release --locked --recipe-path recipe.json --bin ilqr-service
# Now the real sources; only this layer and below are invalidated by code edits.
COPY . .
RUN cargo build --release --locked --bin ilqr-service

# ---------------------------------------------------------------------------
# Runtime: distroless "cc" = glibc + libgcc_s + CA certs, no shell, no package
# manager, so the attack surface is just our binary. The :nonroot variant
# already defaults to uid/gid 65532; it is restated numerically below so that
# Kubernetes' runAsNonRoot can verify it without resolving a user name.
FROM gcr.io/distroless/cc-debian12:nonroot AS runtime

# Build-time metadata; override with --build-arg (e.g. from CI: the git SHA).
ARG VERSION=0.1.0
ARG REVISION=unknown
LABEL org.opencontainers.image.title="ilqr-service" \
      org.opencontainers.image.description="Trajectory optimisation with iLQR, served over HTTP and gRPC" \
      org.opencontainers.image.version="${VERSION}" \
      org.opencontainers.image.revision="${REVISION}" \
      org.opencontainers.image.licenses="MIT OR Apache-2.0" \
      org.opencontainers.image.source="https://example.invalid/ilqr-service" \
      org.opencontainers.image.base.name="gcr.io/distroless/cc-debian12:nonroot"

# The binary is owned by root and not writable by the runtime user, so a
# compromised process cannot replace it. The release profile keeps line
# tables (debug = "line-tables-only"), so panics still give usable backtraces.
COPY --from=builder /app/target/release/ilqr-service /usr/local/bin/ilqr-service

# Bind on all interfaces inside the container (loopback would be unreachable
# through the published ports): HTTP and gRPC. ILQR_GRPC_BIND is set, not
# left to the default, so that a gRPC port that cannot be bound stops the
# container instead of leaving it serving HTTP only. RUST_LOG feeds
# tracing-subscriber's EnvFilter.
# `docker stop` (and compose) send SIGKILL 10 s after SIGTERM by default. The
# binary's default drain is 10 s, so solves it cancels at the end would never
# be answered; 7 s leaves time for that. (After the drain, connections get up
# to 5 s more to finish writing their answers; only a client too slow to
# read its answer in 3 s is cut off by the SIGKILL.) To drain longer, raise both:
# `docker run --stop-timeout 40 -e ILQR_SHUTDOWN_GRACE_SECS=30` (compose:
# `stop_grace_period`). Kubernetes gives 30 s and sets its own value.
ENV ILQR_BIND=0.0.0.0:8080 \
    ILQR_GRPC_BIND=0.0.0.0:50051 \
    ILQR_SHUTDOWN_GRACE_SECS=7 \
    RUST_LOG=info

# HTTP/JSON, and gRPC (ilqr.v1.TrajectoryOptimizer, grpc.health.v1,
# reflection).
EXPOSE 8080 50051

USER 65532:65532

# There is no shell or curl in distroless, so the health check is the binary
# itself: `healthcheck` does a raw HTTP GET /healthz at ILQR_BIND (on
# 127.0.0.1 at its port when it binds every interface, as above) and exits
# 0/1. So `docker run -e
# ILQR_BIND=0.0.0.0:9000` moves the check with the service; a `--bind` flag
# in the command does not (set ILQR_HEALTHCHECK_ADDR too, see
# `ilqr-service healthcheck --help`).
# Exec form, because shell form would need /bin/sh. Kubernetes ignores
# HEALTHCHECK and uses the probes in deploy/k8s/deployment.yaml; this one is
# for docker / compose.
HEALTHCHECK --interval=10s --timeout=3s --start-period=5s --retries=3 \
    CMD ["/usr/local/bin/ilqr-service", "healthcheck"]

# Exec form: the service runs as PID 1 and receives SIGTERM directly from
# `docker stop` / the kubelet, which triggers its graceful drain. A shell
# wrapper would swallow the signal. `docker run ilqr-service solve ...` etc.
# replaces only CMD, reusing the same entrypoint.
ENTRYPOINT ["/usr/local/bin/ilqr-service"]
CMD ["serve"]
