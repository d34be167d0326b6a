# Sourced by .ci/run: start a throwaway one-node Slurm cluster on this machine for tests/test_slurm.py and
# export SLURM_CONF (which sbatch, squeue and scancel read) and CARTPOLE_TEST_SLURM=1.
# Everything lives in a temporary folder: the config, munged's key and socket, slurmctld's state,
# slurmd's spool and every log; `cartpole_slurm_stop` cancels the cluster's jobs, stops the three
# daemons and deletes the folder (also when the sourcing shell exits). Run by hand:
#   source .ci/postgres.sh && source .ci/slurm.sh && python -m pytest -m slow -n 0 tests/test_slurm.py
# Needs root: it installs Debian's slurm-wlm and munge where sbatch or slurmctld is missing, and runs the
# daemons as root (SlurmUser=root), munged as the munge user. The node is this machine (its CPUs and
# memory, as `slurmd -C` finds them), named localhost; slurmctld and slurmd talk over 127.0.0.1 on two
# free ports, jobs are tracked by process tree (proctrack/linuxproc, task/none: no cgroups, so it also
# runs in a container).

cartpole_slurm_install() {
  command -v sbatch >/dev/null 2>&1 && command -v slurmctld >/dev/null 2>&1 && command -v munged >/dev/null 2>&1 \
    && return 0
  if [ "$(id -u)" = 0 ]; then
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq slurm-wlm munge >/dev/null
  else
    sudo apt-get update -qq && sudo DEBIAN_FRONTEND=noninteractive apt-get install -y -qq slurm-wlm munge >/dev/null
  fi
}

cartpole_free_port() {
  python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'
}

cartpole_slurm_stop() {
  [ -n "${CARTPOLE_SLURM_DIR:-}" ] || return 0
  if [ -n "${SLURM_CONF:-}" ] && [ -e "$SLURM_CONF" ]; then
    local jobs
    jobs="$(squeue -h -o %i 2>/dev/null)" || true
    # shellcheck disable=SC2086
    [ -z "$jobs" ] || scancel $jobs 2>/dev/null || true
  fi
  local pidfile pid pids=()
  for pidfile in slurmd.pid slurmctld.pid munge/munged.pid; do
    pid="$(cat "$CARTPOLE_SLURM_DIR/$pidfile" 2>/dev/null)" && kill "$pid" 2>/dev/null && pids+=("$pid")
  done
  for pid in "${pids[@]}"; do  # each takes about 2 s to stop
    for _ in $(seq 100); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
  done
  rm -rf "$CARTPOLE_SLURM_DIR"
  unset CARTPOLE_SLURM_DIR SLURM_CONF CARTPOLE_TEST_SLURM
}

# cartpole_slurm_config DIR: slurm.conf for one node, localhost, with this machine's CPUs and memory.
cartpole_slurm_config() {
  local dir=$1 hardware
  hardware="$(slurmd -C | head -1 | sed 's/^NodeName=[^ ]* //')"
  cat <<EOF
ClusterName=cartpole-ci
SlurmctldHost=localhost(127.0.0.1)
SlurmctldPort=$(cartpole_free_port)
SlurmdPort=$(cartpole_free_port)
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$dir/munge/munge.socket
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/slurmctld.log
SlurmdLogFile=$dir/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
SchedulerType=sched/backfill
MpiDefault=none
CommunicationParameters=NoCtldInAddrAny,NoInAddrAny
ReturnToService=2
SlurmdTimeout=300
InactiveLimit=0
KillWait=30
NodeName=localhost NodeAddr=127.0.0.1 $hardware State=UNKNOWN
PartitionName=debug Nodes=localhost Default=YES MaxTime=INFINITE State=UP
EOF
}

cartpole_slurm_start() {
  local dir=$1
  mkdir -p "$dir/munge" "$dir/state" "$dir/spool"
  chmod 755 "$dir"
  # munged: its own key and socket, as the munge user where there is one (it refuses lax permissions).
  dd if=/dev/urandom of="$dir/munge/munge.key" bs=1024 count=1 status=none
  chmod 700 "$dir/munge" && chmod 400 "$dir/munge/munge.key"
  local munge_user=()
  if id munge >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
    chown -R munge: "$dir/munge"
    munge_user=(runuser -u munge --)
  fi
  "${munge_user[@]}" munged --force --socket="$dir/munge/munge.socket" --key-file="$dir/munge/munge.key" \
    --pid-file="$dir/munge/munged.pid" --log-file="$dir/munge/munged.log" --seed-file="$dir/munge/munged.seed"
  cartpole_slurm_config "$dir" > "$dir/slurm.conf"
  export SLURM_CONF="$dir/slurm.conf"
  slurmctld -c
  slurmd -N localhost
  local state="" _
  for _ in $(seq 120); do
    state="$(sinfo -h -n localhost -o %t 2>/dev/null)" || true
    [ "$state" = idle ] && return 0
    sleep 0.5
  done
  echo "Slurm's node did not come up (state: ${state:-none}); slurmctld.log and slurmd.log:" >&2
  tail -n 20 "$dir/slurmctld.log" "$dir/slurmd.log" >&2 || true
  return 1
}

CARTPOLE_SLURM_START=$SECONDS
if cartpole_slurm_install; then
  CARTPOLE_SLURM_DIR="$(mktemp -d /tmp/cartpole-slurm.XXXXXX)"
  # Stopped on exit, before whatever the shell did on exit already (by hand: postgres.sh's stop).
  trap "cartpole_slurm_stop; $(trap -p EXIT | sed -E "s/^trap -- '(.*)' EXIT\$/\1/")" EXIT
fi
if [ -z "${CARTPOLE_SLURM_DIR:-}" ] || ! cartpole_slurm_start "$CARTPOLE_SLURM_DIR"; then
  cartpole_slurm_stop
  echo "no Slurm cluster: installing or starting it failed" >&2
  return 1
fi
export CARTPOLE_TEST_SLURM=1
echo "Slurm for the cluster tests: SLURM_CONF=$SLURM_CONF ($((SECONDS - CARTPOLE_SLURM_START)) s to install and start)"
