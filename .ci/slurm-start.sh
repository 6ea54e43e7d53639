#!/usr/bin/env bash
# Start a single-node SLURM (munge + slurmctld + slurmd) for the tests marked `slurm`.
#
# Usage: .ci/slurm-start.sh [STATE_DIR]     (default ${FEM_RMPM_SLURM_STATE:-/tmp/fem-rmpm-slurm})
#
# * Installs the Debian packages slurmctld, slurmd, slurm-client and munge if they are missing
#   (root; about 15 s).  Nothing is started through systemd: the daemons are started by hand.
# * Writes /etc/slurm/slurm.conf for this host: one node with all its CPUs and its memory less
#   1 GiB, one partition `debug` (the default), no cgroups (proctrack/linuxproc, task/none), no
#   accounting; state, spool, logs and pid files in STATE_DIR.
# * If a SLURM controller already answers (`sinfo` lists an idle node), nothing is started or
#   written: that cluster is used as it is.
# * Every daemon this script starts is listed, by its pid file, in STATE_DIR/started;
#   .ci/slurm-stop.sh STATE_DIR stops exactly those, and nothing else.
# Exit 0 once `sinfo` shows the node idle (typically < 2 s after the start); 1 otherwise.
set -euo pipefail
S=${1:-${FEM_RMPM_SLURM_STATE:-/tmp/fem-rmpm-slurm}}
log() { echo "slurm-start: $*" >&2; }

node_idle() { sinfo -h -N -o %t 2>/dev/null | grep -Eqx 'idle|mix(ed)?|alloc(ated)?'; }

if command -v sinfo >/dev/null 2>&1 && node_idle; then
  log "a SLURM controller already answers; using it, starting nothing"
  mkdir -p "$S"; : > "$S/started"
  exit 0
fi

if ! command -v slurmctld >/dev/null || ! command -v slurmd >/dev/null \
   || ! command -v sbatch >/dev/null || ! command -v munged >/dev/null; then
  log "installing slurmctld slurmd slurm-client munge (Debian packages)"
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq
  apt-get install -y -qq --no-install-recommends slurmctld slurmd slurm-client munge >/dev/null
fi

rm -rf "$S"
mkdir -p "$S/state" "$S/spool" "$S/log"
: > "$S/started"
H=$(hostname -s)
MEM=$(( $(free -m | awk '/^Mem:/{print $2}') - 1024 ))
mkdir -p /etc/slurm
cat > /etc/slurm/slurm.conf <<CONF
# written by fem_rmpm .ci/slurm-start.sh: a single-node cluster for the tests
ClusterName=ci
SlurmctldHost=$H
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
MpiDefault=none
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
ReturnToService=2
MailProg=/bin/true
SlurmctldPidFile=$S/slurmctld.pid
SlurmdPidFile=$S/slurmd.pid
StateSaveLocation=$S/state
SlurmdSpoolDir=$S/spool
SlurmctldLogFile=$S/log/slurmctld.log
SlurmdLogFile=$S/log/slurmd.log
SlurmctldTimeout=30
SlurmdTimeout=30
InactiveLimit=0
MinJobAge=30
KillWait=5
Waittime=0
NodeName=$H CPUs=$(nproc) RealMemory=$MEM State=UNKNOWN
PartitionName=debug Nodes=ALL Default=YES MaxTime=INFINITE State=UP
CONF

# munge: the key is written by the package's postinst; /run/munge must exist and be munge's
if [ ! -s /etc/munge/munge.key ]; then
  mungekey --create --force
  chown munge:munge /etc/munge/munge.key; chmod 400 /etc/munge/munge.key
fi
mkdir -p /run/munge && chown munge:munge /run/munge
if munge -n 2>/dev/null | unmunge >/dev/null 2>&1; then
  log "munged already runs; using it"
else
  runuser -u munge -- /usr/sbin/munged
  echo /run/munge/munged.pid >> "$S/started"
  for _ in $(seq 50); do munge -n 2>/dev/null | unmunge >/dev/null 2>&1 && break; sleep 0.1; done
  munge -n | unmunge >/dev/null || { log "munged does not answer"; exit 1; }
fi

/usr/sbin/slurmctld -c          # daemonizes; -c: clean state
echo "$S/slurmctld.pid" >> "$S/started"
/usr/sbin/slurmd                # daemonizes
echo "$S/slurmd.pid" >> "$S/started"

for _ in $(seq 120); do
  node_idle && { log "node $H idle ($(nproc) CPUs, ${MEM} MB); state in $S"; exit 0; }
  sleep 0.5
done
log "the node did not become idle within 60 s; logs in $S/log:"
tail -n 20 "$S"/log/*.log >&2 || true
exit 1
