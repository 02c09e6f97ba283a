#!/usr/bin/env bash
# Start Debian's PostgreSQL cluster on loopback and create the test role and database
# (user gripper, password gripper, database gripper). Idempotent.
set -euo pipefail
version=$(ls /etc/postgresql 2>/dev/null | sort -V | tail -n 1)
[ -n "$version" ] || { echo "start-postgres: no cluster found" >&2; exit 1; }
pg_ctlcluster "$version" main start 2>/dev/null || true
for _ in $(seq 1 30); do
    pg_isready -h 127.0.0.1 -p 5432 -q && break
    sleep 1
done
su postgres -c "psql -qtAc \"SELECT 1 FROM pg_roles WHERE rolname='gripper'\"" | grep -q 1 \
    || su postgres -c "psql -qc \"CREATE ROLE gripper LOGIN PASSWORD 'gripper'\""
# the distributed-study test creates a fresh database per run (the table-creation race)
su postgres -c "psql -qc \"ALTER ROLE gripper CREATEDB\""
su postgres -c "psql -qtAc \"SELECT 1 FROM pg_database WHERE datname='gripper'\"" | grep -q 1 \
    || su postgres -c "createdb -O gripper gripper"
echo "start-postgres: postgresql $version on 127.0.0.1:5432"
