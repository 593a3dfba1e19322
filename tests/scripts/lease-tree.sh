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

# --baseline REV builds that commit's pvrnn in a worktree beside the checkout (a stand-in
# cargo here writes /bin/true as the binary) and leaves it compressed in lease/, the
# worktree gone; a name that is no commit is refused before anything is built.
scripts/lease-tree.sh unpack 2>/dev/null || true
git reset -q
mkdir -p "$work/bin"
cat > "$work/bin/cargo" <<'FAKE'
#!/usr/bin/env bash
[ "$1" = build ] || exit 1
[ -f crates/a/lib.rs ] || { echo "not in a worktree of the repository" >&2; exit 1; }
mkdir -p "$CARGO_TARGET_DIR/release"
cp /bin/true "$CARGO_TARGET_DIR/release/pvrnn"
FAKE
chmod +x "$work/bin/cargo"
! PATH="$work/bin:$PATH" scripts/lease-tree.sh pack --no-build --baseline no-such-commit 2>/dev/null ||
    fail "--baseline with no such commit was allowed"
PATH="$work/bin:$PATH" CARGO_TARGET_DIR="$work/target" \
    scripts/lease-tree.sh pack --no-build --baseline HEAD 2> "$work/pack.log" ||
    fail "pack --baseline: $(cat "$work/pack.log")"
[ -f lease/pvrnn-before.gz ] || fail "no lease/pvrnn-before.gz"
[ "$(gunzip -c lease/pvrnn-before.gz | head -c 4 | tail -c 3)" = ELF ] ||
    fail "lease/pvrnn-before.gz is not the compressed binary"
[ "$(git worktree list | wc -l)" = 1 ] || fail "the baseline's worktree was left: $(git worktree list)"
scripts/lease-tree.sh unpack 2>/dev/null || fail "unpack after --baseline"
echo "lease-tree test: passed"
