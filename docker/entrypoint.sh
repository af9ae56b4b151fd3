#!/bin/sh
# Entry point of Glint's images (docker/Dockerfile).
#   serve       the API on 0.0.0.0:8000; with GLINT_BACKEND=ray and no GLINT_RAY_ADDRESS, first a
#               Ray head node in this container (RAY_HEAD_CPUS CPUs for tasks, default 0: the work
#               goes to the worker nodes), which the API then joins as its driver
#   ray-worker  a Ray worker node joining RAY_HEAD (host name of the server container), in the
#               foreground; RAY_NUM_CPUS CPUs (default: the container's)
#   anything else is run as a command (e.g. glint token create, glint db upgrade)
set -eu

role="${1:-serve}"
case "$role" in
  serve)
    if [ "${GLINT_BACKEND:-local}" = "ray" ] && [ -z "${GLINT_RAY_ADDRESS:-}" ]; then
      ray start --head --port=6379 --num-cpus="${RAY_HEAD_CPUS:-0}" --include-dashboard=false \
        --disable-usage-stats --object-store-memory="${RAY_OBJECT_STORE_BYTES:-500000000}"
      GLINT_RAY_ADDRESS=auto
      export GLINT_RAY_ADDRESS
    fi
    # listening beyond loopback: clients need an API token (glint token create)
    exec glint serve --host 0.0.0.0 --port 8000 --no-demo
    ;;
  ray-worker)
    : "${RAY_HEAD:?set RAY_HEAD to the host name of the server (Ray head) container}"
    set -- --address="${RAY_HEAD}:6379" --block --disable-usage-stats \
      --object-store-memory="${RAY_OBJECT_STORE_BYTES:-500000000}"
    if [ -n "${RAY_NUM_CPUS:-}" ]; then
      set -- "$@" --num-cpus="${RAY_NUM_CPUS}"
    fi
    exec ray start "$@"
    ;;
  *)
    exec "$@"
    ;;
esac
