#!/usr/bin/env bash
# scripts/lease-tree.sh on a scratch repository: pack drops the folders a GPU call does not
# need from the index and ignores them (with --campaign keeping the interference results
# and a kept training), refuses to pack twice or over staged changes, and unpack gives the
# index and the exclude file back as they were; the files never leave the disk.
set -euo pipefail
scripts=$(realpath "$(dirname "$0")/../../scripts")
work=$(mktemp -d /tmp/pvrnn-lease-tree.XXXXXX)
trap 'rm -rf "$work"' EXIT
fail() { echo "lease-tree test: $*" >&2; exit 1; }

repo=$work/repo
mkdir -p "$repo/scripts" "$repo/crates/a" "$repo/models" "$repo/docs/results/converged/interference" \
    "$repo/docs/results/gpu" "$repo/training/in-flight" "$repo/training/recipes" "$repo/.gl"
cd "$repo"
git init -q
cp "$scripts/lease-tree.sh" scripts/
echo code > crates/a/lib.rs
echo model > models/default.safetensors
echo plan > docs/results/converged/interference/plan.json
echo notes > docs/results/gpu/notes.md
echo doc > docs/gpu.md
echo kept > training/in-flight/checkpoint.safetensors
echo recipe > training/recipes/a.toml
echo deb > .gl/libvulkan1_1.0_amd64.deb
mkdir -p .git/info
echo "/target" > .git/info/exclude
git add -A crates models docs training scripts
git -c user.name=t -c user.email=t@t commit -q -m init
before_exclude=$(cat .git/info/exclude)

scripts/lease-tree.sh pack --campaign --no-build 2> "$work/pack.log" || fail "pack: $(cat "$work/pack.log")"
grep -q "MiB would travel" "$work/pack.log" || fail "pack does not say what travels: $(cat "$work/pack.log")"
tracked=$(git ls-files | sort | tr '\n' ' ')
[ "$tracked" = "crates/a/lib.rs docs/results/converged/interference/plan.json scripts/lease-tree.sh training/in-flight/checkpoint.safetensors " ] ||
    fail "the index after pack --campaign: $tracked"
untracked=$(git ls-files --others --exclude-standard | tr '\n' ' ')
[ -z "$untracked" ] || fail "dropped folders still travel as untracked files: $untracked"
[ -f models/default.safetensors ] && [ -f docs/gpu.md ] || fail "pack removed files from the disk"
grep -qxF "/lease/" .git/info/exclude && grep -qxF "/.gl/" .git/info/exclude ||
    fail "lease/ and .gl/ are not ignored"
! scripts/lease-tree.sh pack --no-build 2>/dev/null || fail "a second pack was allowed"

scripts/lease-tree.sh unpack 2>/dev/null || fail "unpack failed"
git diff --cached --quiet || fail "the index differs from HEAD after unpack"
[ -z "$(git status --porcelain)" ] || fail "the tree is not clean after unpack: $(git status --porcelain)"
# The carried folders stay ignored; everything pack added for the calls is gone.
[ "$(cat .git/info/exclude)" = "$before_exclude"$'\n/lease/\n/.gl/' ] ||
    fail "the exclude file after unpack: $(cat .git/info/exclude)"

# Without --campaign nothing of docs/ or training/ travels; staged changes are refused.
scripts/lease-tree.sh pack --no-build 2>/dev/null || fail "pack without --campaign"
[ "$(git ls-files | tr '\n' ' ')" = "crates/a/lib.rs scripts/lease-tree.sh " ] ||
    fail "the index after pack: $(git ls-files | tr '\n' ' ')"
scripts/lease-tree.sh unpack 2>/dev/null
echo change >> crates/a/lib.rs
git add crates/a/lib.rs
! scripts/lease-tree.sh pack --no-build 2>/dev/null || fail "pack over staged changes was allowed"
echo "lease-tree test: passed"
