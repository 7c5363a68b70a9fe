#!/usr/bin/env bash
# Mutation testing of the two pure safety-rule modules with cosmic-ray (docs/mutation.md):
# federation/core/holds.py (the safety supervisor) and federation/core/runstate.py (the
# run's modes). From the repository's root:
#
#     bash tests/mutation/run.sh              # both modules
#     bash tests/mutation/run.sh runstate     # one (holds, runstate)
#
# Mutants inside type annotations are skipped, not run (skip_annotations.py says why).
# The mutants are written into a copy of the tree (its tracked and new files, as they
# stand) in a temporary folder, never into the working tree, so a run disturbs no one
# else's tests. One worker (the local distributor): the machine is shared. The session
# files stay in that folder and go with it, unless MUTATION_SESSIONS names a folder to
# keep them in (to read the survivors' diffs: .venv/bin/cr-report --show-diff FILE).
set -euo pipefail
cd "$(dirname "$0")/../.."
root=$(pwd -P)
[ -x .venv/bin/cosmic-ray ] || { echo "no .venv/bin/cosmic-ray: pip install -e '.[dev]'" >&2; exit 2; }
modules=("$@")
[ ${#modules[@]} -gt 0 ] || modules=(holds runstate)

work=$(mktemp -d "${TMPDIR:-/tmp}/fedlab-mutation.XXXXXX")
trap 'rm -rf "$work"' EXIT
work=$(cd "$work" && pwd -P)
sessions=${MUTATION_SESSIONS:-$work/sessions}
mkdir -p "$sessions"
sessions=$(cd "$sessions" && pwd -P)

git ls-files -z --cached --others --exclude-standard -- \
    federation schemas agents tests docs pyproject.toml |
    tar --null --files-from=- --ignore-failed-read -cf - 2>/dev/null | tar -xf - -C "$work"
ln -s "$root/.venv" "$work/.venv"
cd "$work"
# The copy, not the working tree's editable install, must be what the tests import.
.venv/bin/python -c '
import sys
import federation.core.holds as h, federation.core.runstate as r
assert h.__file__.startswith(sys.argv[1]) and r.__file__.startswith(sys.argv[1]), h.__file__
' "$work"

summary=()
for m in "${modules[@]}"; do
    config="tests/mutation/$m.toml"
    session="$sessions/$m.sqlite"
    [ -f "$config" ] || { echo "no $config" >&2; exit 2; }
    echo "=== $m: $(grep -m1 '^module-path' "$config")"
    .venv/bin/cosmic-ray init --force "$config" "$session"
    .venv/bin/python tests/mutation/skip_annotations.py "$session"
    .venv/bin/cosmic-ray baseline "$config"
    .venv/bin/cosmic-ray exec "$config" "$session"
    .venv/bin/cr-report --surviving-only --show-diff "$session"
    line="$m: $(.venv/bin/python tests/mutation/skip_annotations.py --summary "$session")"
    echo "=== $line"
    summary+=("$line")
done
printf '%s\n' "${summary[@]}"
