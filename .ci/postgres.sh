# Sourced by .ci/run: start a throwaway PostgreSQL cluster for the sweep tests and export its URL.
#   CARTPOLE_TEST_POSTGRES_URL=postgresql://postgres@127.0.0.1:PORT/cartpole
# The cluster lives in a temporary folder, listens on 127.0.0.1 only (trust auth: nothing else can reach
# it), and is stopped and deleted when the sourcing shell exits. Run by hand:
#   source .ci/postgres.sh && python -m pytest tests/test_sweep_postgres.py
# Needs root (to install Debian's postgresql and run it as the postgres user) or an existing postgres user.

cartpole_pg_bin() {
  local dir
  # /usr/local/bin may hold links to initdb and pg_ctl only: follow them to the full bin folder.
  for dir in "$(dirname "$(readlink -f "$(command -v initdb 2>/dev/null || echo /nonexistent/x)")")" \
             /usr/lib/postgresql/*/bin; do
    if [ -x "$dir/initdb" ] && [ -x "$dir/pg_ctl" ] && [ -x "$dir/createdb" ]; then echo "$dir"; return 0; fi
  done
  return 1
}

if ! cartpole_pg_bin >/dev/null; then
  if [ "$(id -u)" = 0 ]; then apt-get update -qq && apt-get install -y -qq postgresql >/dev/null
  else sudo apt-get update -qq && sudo apt-get install -y -qq postgresql >/dev/null; fi
fi
CARTPOLE_PG_BIN="$(cartpole_pg_bin)"
CARTPOLE_PG_DIR="$(mktemp -d /tmp/cartpole-pg.XXXXXX)"
chown postgres: "$CARTPOLE_PG_DIR" 2>/dev/null || true
CARTPOLE_PG_PORT="$(python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')"

cartpole_as_postgres() {
  if [ "$(id -un)" = postgres ]; then "$@"; else runuser -u postgres -- "$@"; fi
}

cartpole_pg_stop() {
  cartpole_as_postgres "$CARTPOLE_PG_BIN/pg_ctl" -D "$CARTPOLE_PG_DIR/data" -m immediate stop >/dev/null 2>&1 || true
  rm -rf "$CARTPOLE_PG_DIR"
}
trap cartpole_pg_stop EXIT

cartpole_as_postgres "$CARTPOLE_PG_BIN/initdb" -D "$CARTPOLE_PG_DIR/data" -U postgres --auth=trust >/dev/null
# max_connections: benchmarks/claims.py --workers 256 holds a connection per simulated worker (default: 100).
cartpole_as_postgres "$CARTPOLE_PG_BIN/pg_ctl" -D "$CARTPOLE_PG_DIR/data" -l "$CARTPOLE_PG_DIR/server.log" -w \
  -o "-c listen_addresses=127.0.0.1 -p $CARTPOLE_PG_PORT -k $CARTPOLE_PG_DIR -c max_connections=400" start >/dev/null
cartpole_as_postgres "$CARTPOLE_PG_BIN/createdb" -h 127.0.0.1 -p "$CARTPOLE_PG_PORT" -U postgres cartpole
export CARTPOLE_TEST_POSTGRES_URL="postgresql://postgres@127.0.0.1:$CARTPOLE_PG_PORT/cartpole"
echo "PostgreSQL for the sweep tests: $CARTPOLE_TEST_POSTGRES_URL"
