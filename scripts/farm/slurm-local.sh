#!/usr/bin/env bash
# A one-node Slurm cluster on this machine, for tests and benchmarks (issue #20):
#
#   scripts/farm/slurm-local.sh start DIR [CPUS]   # munged, slurmctld, slurmd; state in DIR
#   eval "$(scripts/farm/slurm-local.sh env DIR)"  # SLURM_CONF for sbatch, squeue, scancel
#   scripts/farm/slurm-local.sh stop DIR           # stops the daemons started by start
#
# Needs root and Debian's slurm-wlm and munge (scripts/install-deps.sh). Its own munge key
# and socket, its own ports (from the DIR's name, so two clusters do not collide), one node
# (this host, CPUS cores, default all), one partition `nimbus`, proctrack/linuxproc and
# task/none: no cgroups, no systemd, no accounting.
set -euo pipefail
cmd=${1:?usage: slurm-local.sh start|stop|env DIR [CPUS]}
dir=$(realpath -m "${2:?usage: slurm-local.sh start|stop|env DIR [CPUS]}")
cpus=${3:-$(nproc)}

case "$cmd" in
env)
  echo "export SLURM_CONF=$dir/slurm.conf"
  exit 0
  ;;
stop)
  for pidfile in "$dir/slurmd.pid" "$dir/slurmctld.pid" "$dir/munged.pid"; do
    if [ -s "$pidfile" ]; then
      pid=$(cat "$pidfile")
      kill "$pid" 2>/dev/null || true
      for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
      kill -9 "$pid" 2>/dev/null || true
      rm -f "$pidfile"
    fi
  done
  exit 0
  ;;
start) ;;
*) echo "slurm-local.sh: unknown command '$cmd' (start, stop, env)" >&2; exit 2 ;;
esac

if [ "$(id -u)" -ne 0 ]; then
  echo "error: slurm-local.sh needs root (slurmd runs jobs as their users) ($dir)" >&2
  exit 2
fi
for tool in munged mungekey slurmctld slurmd sbatch; do
  command -v "$tool" >/dev/null || { echo "error: $tool is not installed (scripts/install-deps.sh installs slurm-wlm and munge)" >&2; exit 2; }
done
mkdir -p "$dir"/{state,spool,munge}
chmod 700 "$dir" "$dir/munge"
host=$(hostname -s)
# Ports from the directory's name: 20000 + (cksum mod 20000), two apart.
sum=$(printf '%s' "$dir" | cksum | cut -d' ' -f1)
port=$((20000 + (sum % 20000) / 2 * 2))

[ -s "$dir/munge/munge.key" ] || mungekey --create --keyfile="$dir/munge/munge.key" --bits=1024
chmod 400 "$dir/munge/munge.key"
munged --force --key-file="$dir/munge/munge.key" --socket="$dir/munge/munge.socket" \
  --pid-file="$dir/munged.pid" --log-file="$dir/munged.log" --seed-file="$dir/munge/munge.seed"

cat > "$dir/slurm.conf" <<CONF
# Written by scripts/farm/slurm-local.sh: a one-node test cluster.
ClusterName=nimbus
SlurmctldHost=$host(127.0.0.1)
SlurmctldPort=$port
SlurmdPort=$((port + 1))
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$dir/munge/munge.socket
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool/%n
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/slurmctld.log
SlurmdLogFile=$dir/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
MpiDefault=none
SchedulerType=sched/builtin
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
AccountingStorageType=accounting_storage/none
JobAcctGatherType=jobacct_gather/none
JobCompType=jobcomp/none
ReturnToService=2
KillWait=2
MinJobAge=300
SlurmdTimeout=30
NodeName=$host NodeAddr=127.0.0.1 CPUs=$cpus State=UNKNOWN
PartitionName=nimbus Nodes=$host Default=YES MaxTime=INFINITE State=UP OverSubscribe=NO
CONF
slurmctld -f "$dir/slurm.conf" -i
slurmd -f "$dir/slurm.conf"
export SLURM_CONF=$dir/slurm.conf
for _ in $(seq 100); do
  if sinfo -h -o '%T' 2>/dev/null | grep -qE '^(idle|mixed|allocated)'; then
    exit 0
  fi
  sleep 0.2
done
echo "error: the Slurm node did not come up in 20 s (logs in $dir)" >&2
sinfo >&2 || true
tail -5 "$dir/slurmctld.log" "$dir/slurmd.log" >&2 || true
exit 1
