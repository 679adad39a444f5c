#!/bin/bash
# Starts a single-node Slurm on this machine (as root, without systemd):
# munged, slurmctld and slurmd with a minimal configuration, one partition
# holding this host. CI uses it to run scripts/slurm_render.sh for real;
# it needs Debian's slurm-wlm and munge (apt-get install slurm-wlm munge).
# Does nothing when a node already answers.
set -euo pipefail
if sinfo -h -o %T 2>/dev/null | grep -qE 'idle|mix|alloc'; then
    exit 0
fi
host=$(hostname -s)
mkdir -p /etc/slurm /var/spool/slurmd /var/spool/slurmctld /run/slurm /var/log/slurm /run/munge
chown munge:munge /run/munge
if ! munge -n >/dev/null 2>&1; then
    [ -f /etc/munge/munge.key ] || { mungekey --create 2>/dev/null || create-munge-key -f; }
    runuser -u munge -- /usr/sbin/munged
fi
cat > /etc/slurm/slurm.conf <<CONF
ClusterName=qtrace
SlurmctldHost=$host
AuthType=auth/munge
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
SchedulerType=sched/builtin
SlurmctldPidFile=/run/slurm/slurmctld.pid
SlurmdPidFile=/run/slurm/slurmd.pid
SlurmdSpoolDir=/var/spool/slurmd
StateSaveLocation=/var/spool/slurmctld
SlurmUser=root
SlurmdUser=root
ReturnToService=2
MpiDefault=none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
SlurmctldLogFile=/var/log/slurm/slurmctld.log
SlurmdLogFile=/var/log/slurm/slurmd.log
NodeName=$host CPUs=$(nproc) State=UNKNOWN
PartitionName=qtrace Nodes=ALL Default=YES MaxTime=INFINITE State=UP
CONF
/usr/sbin/slurmctld
/usr/sbin/slurmd
for _ in $(seq 1 30); do
    if sinfo -h -o %T 2>/dev/null | grep -qE 'idle|mix|alloc'; then
        echo "single-node Slurm up on $host"
        exit 0
    fi
    sleep 1
done
echo "slurm_single_node.sh: the node did not come up; see /var/log/slurm/" >&2
exit 1
