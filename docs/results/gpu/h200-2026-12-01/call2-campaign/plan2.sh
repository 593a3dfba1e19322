#!/usr/bin/env bash
set -uo pipefail
date -u
COHORT=3 THREADS=16 scripts/lease-campaign.sh lease/pvrnn $OUT/c 500
date -u
