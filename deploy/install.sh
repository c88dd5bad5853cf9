#!/usr/bin/env bash
# Install or update vdm-aero as a systemd service on a companion computer. Run as root.
#
#   sudo deploy/install.sh --models /path/to/models            # first install
#   sudo deploy/install.sh                                     # update the code, keep models and config
#   deploy/install.sh --dry-run --models DIR                   # print the plan, change nothing
#
# Idempotent: each step compares before it acts, so a second run with the same inputs changes nothing.
# Offline install (no index on the vehicle): pip reads PIP_NO_INDEX=1 PIP_FIND_LINKS=/path/to/wheelhouse.
set -euo pipefail

readonly SERVICE=vdm-aero
readonly USER_NAME=vdm-aero
# The install prefix written in deploy/vdm-aero.service and config.yaml; render replaces it with --prefix.
readonly TEMPLATE_PREFIX=/opt/vdm-aero

script_dir=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
template="$script_dir/vdm-aero.service"

usage() {
	cat <<EOF
usage: $0 [options]
  --dry-run       print every action (prefixed 'would:') and change nothing
  --prefix DIR    install prefix (default $TEMPLATE_PREFIX): DIR/venv, DIR/models
  --source DIR    vdm-aero source tree to pip install (default: $(dirname "$script_dir"))
  --models DIR    models directory, copied to PREFIX/models (required unless already installed)
  --config FILE   default config (default: $script_dir/config.yaml); installed to /etc/vdm-aero/config.yaml
                  only if none is there, else as config.yaml.new next to the operator's
  --python PY     interpreter for the venv (default python3; the package needs 3.11)
  --no-start      install the unit, but neither enable nor start (nor restart) the service
  --root DIR      act on the tree under DIR instead of / (tests, staging): every /etc and PREFIX path is
                  taken under DIR, systemctl gets --root and nothing is started; the venv only runs from DIR
  --print-unit    print the unit rendered for --prefix and exit (what gets installed)
EOF
}

die() {
	printf 'install.sh: %s\n' "$*" >&2
	exit 1
}

dry_run=0
start=1
print_unit=0
prefix=$TEMPLATE_PREFIX
source_dir=$(dirname "$script_dir")
models=""
config="$script_dir/config.yaml"
python=python3
root=/

while (($#)); do
	case $1 in
	--dry-run) dry_run=1 ;;
	--no-start) start=0 ;;
	--print-unit) print_unit=1 ;;
	--prefix | --source | --models | --config | --python | --root)
		(($# >= 2)) || die "$1 needs a value"
		case $1 in
		--prefix) prefix=$2 ;;
		--source) source_dir=$2 ;;
		--models) models=$2 ;;
		--config) config=$2 ;;
		--python) python=$2 ;;
		--root) root=$2 ;;
		esac
		shift
		;;
	-h | --help)
		usage
		exit 0
		;;
	*) die "unknown option: $1 (see --help)" ;;
	esac
	shift
done

# The prefix goes into ExecStart= unquoted and into a sed replacement: plain absolute paths only.
prefix=${prefix%/}
[[ $prefix =~ ^/[A-Za-z0-9._+/-]+$ ]] || die "--prefix must be an absolute path of [A-Za-z0-9._+/-]: $prefix"

render() { # render PREFIX < shipped > installed: the unit or the config for PREFIX (tests: --print-unit)
	sed "s|$TEMPLATE_PREFIX/|$1/|g"
}

if ((print_unit)); then
	render "$prefix" <"$template"
	exit 0
fi

[[ -d $root ]] || die "--root $root is not a directory"
R=$(cd "$root" && pwd)
[[ $R == / ]] && R=""
((dry_run)) || ((EUID == 0)) || die "run as root (or use --dry-run)"

quote() { # the words as a shell would need them, bare where that is unambiguous
	local word out=()
	for word in "$@"; do
		if [[ $word =~ ^[A-Za-z0-9_./=:,+@%-]+$ ]]; then out+=("$word"); else out+=("$(printf '%q' "$word")"); fi
	done
	printf '%s' "${out[*]}"
}

# run CMD...: print the command, then run it; under --dry-run only print it.
run() {
	if ((dry_run)); then
		printf 'would: %s\n' "$(quote "$@")"
	else
		printf 'run: %s\n' "$(quote "$@")"
		"$@"
	fi
}

ok() { printf 'ok: %s\n' "$*"; }

# Paths as the target system sees them (written into the unit and config) vs. where this run touches them.
etc_dir=/etc/vdm-aero
cfg=$etc_dir/config.yaml
unit_path=/etc/systemd/system/$SERVICE.service
venv="$R$prefix/venv"
stamp="$venv/.vdm-aero-source.sha256"
changed=0 # anything the running service would have to be restarted for

root_opt=()
[[ -n $R ]] && root_opt=(--root "$R")

user_exists() {
	if [[ -z $R ]]; then
		getent passwd "$USER_NAME" >/dev/null
	else
		grep -q "^$USER_NAME:" "$R/etc/passwd" 2>/dev/null
	fi
}

in_dialout() {
	if [[ -z $R ]]; then
		id -nG "$USER_NAME" | tr ' ' '\n' | grep -qx dialout
	else
		grep -Eq "^dialout:[^:]*:[^:]*:(.*,)?$USER_NAME(,|$)" "$R/etc/group" 2>/dev/null
	fi
}

# The service group for install -g: numeric under --root, where the host's NSS does not know the tree's groups.
service_group() {
	local gid=""
	[[ -n $R ]] && gid=$(awk -F: -v g="$USER_NAME" '$1 == g { print $3 }' "$R/etc/group" 2>/dev/null)
	printf '%s' "${gid:-$USER_NAME}"
}

# Content hash of the source tree pip builds from: a changed tree is reinstalled, an unchanged one is not.
source_hash() {
	(
		cd "$source_dir"
		find . -mindepth 1 \( -name '.*' -o -name __pycache__ -o -name '*.egg-info' -o -name build -o -name out \) \
			-prune -o -type f -print0 | sort -z | xargs -0 sha256sum | sha256sum | cut -d' ' -f1
	)
}

# --- inputs -------------------------------------------------------------------------------------------
[[ -f $template ]] || die "unit template not found: $template"
[[ -f $source_dir/pyproject.toml || -f $source_dir/setup.py ]] || die "--source $source_dir is not a Python project"
source_dir=$(cd "$source_dir" && pwd)
[[ -f $config ]] || die "config not found: $config (pass --config FILE)"
shipped=$config # the config as it would be installed: its model paths follow --prefix
if [[ $prefix != "$TEMPLATE_PREFIX" ]]; then
	shipped=$(mktemp)
	trap 'rm -f "$shipped"' EXIT
	render "$prefix" <"$config" >"$shipped"
	printf 'note: %s rendered for prefix %s is %s\n' "$config" "$prefix" "$shipped"
fi
if [[ -n $models ]]; then
	[[ -d $models ]] || die "--models $models is not a directory"
elif [[ ! -d $R$prefix/models ]]; then
	die "no models installed in $prefix/models yet: pass --models DIR"
fi

# --- service user: no login, no home; dialout for a direct serial link to the flight controller ------------
if ! user_exists; then
	run useradd "${root_opt[@]}" --system --user-group --no-create-home --home-dir /nonexistent \
		--shell /usr/sbin/nologin --groups dialout "$USER_NAME"
elif ! in_dialout; then
	run usermod "${root_opt[@]}" --append --groups dialout "$USER_NAME"
else
	ok "user $USER_NAME exists and is in dialout"
fi
group=$(service_group)

# --- venv and package ------------------------------------------------------------------------------------
[[ -d $R$prefix ]] || run install -d -m 0755 "$R$prefix"
if [[ -x $venv/bin/python ]]; then
	ok "venv $venv exists"
else
	run "$python" -m venv "$venv"
fi

hash=$(source_hash)
if [[ -f $stamp && $(<"$stamp") == "$hash" ]]; then
	ok "package from $source_dir already installed (source unchanged)"
else
	# The plain path, no [extras]: the runtime gets the base dependencies only (no torch, no simulator).
	run "$venv/bin/pip" install --disable-pip-version-check --upgrade "$source_dir"
	if ((dry_run)); then
		printf 'would: record the source hash in %s\n' "$stamp"
	else
		printf '%s\n' "$hash" >"$stamp"
	fi
	changed=1
fi

# --- models: copied beside the old ones, then renamed in, so the service never reads a half copy -----------
dest="$R$prefix/models"
if [[ -z $models ]]; then
	ok "keeping the installed models in $dest"
elif [[ -d $dest ]] && diff -rq "$models" "$dest" >/dev/null 2>&1; then
	ok "models in $dest are up to date"
else
	tmp="$R$prefix/.models.new"
	old="$R$prefix/.models.old"
	for leftover in "$tmp" "$old"; do
		if [[ -e $leftover ]]; then # from an interrupted run
			run rm -rf "$leftover"
		fi
	done
	run cp -R "$models" "$tmp"
	run chmod -R u=rwX,go=rX "$tmp"
	if [[ -e $dest ]]; then
		# Two renames: the window without models is one syscall long, and the service reads them at start.
		run mv -T "$dest" "$old"
		run mv -T "$tmp" "$dest"
		run rm -rf "$old"
	else
		run mv -T "$tmp" "$dest"
	fi
	changed=1
fi

# --- config: never overwrite an operator's edits ------------------------------------------------------
[[ -d $R$etc_dir ]] || run install -d -m 0750 -o root -g "$group" "$R$etc_dir"
if [[ ! -e $R$cfg ]]; then
	run install -m 0640 -o root -g "$group" "$shipped" "$R$cfg"
	changed=1
elif cmp -s "$shipped" "$R$cfg"; then
	ok "$cfg is the shipped config"
else
	printf 'keep: %s differs from %s; the operator'\''s file stays, the shipped one goes to %s.new\n' \
		"$cfg" "$config" "$cfg"
	if [[ -e $R$cfg.new ]] && cmp -s "$shipped" "$R$cfg.new"; then
		ok "$cfg.new is up to date"
	else
		run install -m 0640 -o root -g "$group" "$shipped" "$R$cfg.new"
	fi
fi

# --- check the config the service will read, before systemd is told about anything ----------------------
check=("$venv/bin/vdm-aero" serve --check-config --config "$R$cfg")
# As the service user where there is one: also catches a config or model it could not read.
[[ -z $R ]] && check=(runuser -u "$USER_NAME" -- "${check[@]}")
if ((dry_run)); then
	printf 'would: %s\n' "$(quote "${check[@]}")"
else
	printf 'run: %s\n' "$(quote "${check[@]}")"
	if ! msg=$("${check[@]}" 2>&1); then
		die "config check failed, nothing enabled: ${msg:-no message}"
	fi
	if [[ -n $msg ]]; then
		ok "$msg"
	fi
fi

# --- unit ---------------------------------------------------------------------------------------------
unit_changed=0
if [[ -f $R$unit_path ]] && render "$prefix" <"$template" | cmp -s - "$R$unit_path"; then
	ok "$unit_path is up to date"
else
	if ((dry_run)); then
		printf 'would: render %s with prefix %s to %s\n' "$template" "$prefix" "$R$unit_path"
	else
		printf 'run: render %s with prefix %s to %s\n' "$template" "$prefix" "$R$unit_path"
		install -d -m 0755 "$(dirname "$R$unit_path")"
		render "$prefix" <"$template" >"$R$unit_path.tmp"
		chmod 0644 "$R$unit_path.tmp"
		mv -f "$R$unit_path.tmp" "$R$unit_path"
	fi
	unit_changed=1
	changed=1
fi

# --- systemd ------------------------------------------------------------------------------------------
if [[ -n $R ]]; then
	# Not the running system: only the enable symlink can be made, offline.
	if ((!start)); then
		ok "not enabling (--no-start)"
	elif systemctl --root "$R" is-enabled --quiet "$SERVICE" 2>/dev/null; then
		ok "$SERVICE enabled under $R"
	else
		run systemctl --root "$R" enable "$SERVICE"
	fi
	exit 0
fi

if ((unit_changed)); then
	run systemctl daemon-reload
fi
if ((!start)); then
	ok "not enabling or starting (--no-start)"
	if ((changed)); then
		printf 'note: restart %s to use what changed\n' "$SERVICE"
	fi
elif systemctl is-enabled --quiet "$SERVICE" 2>/dev/null && systemctl is-active --quiet "$SERVICE" 2>/dev/null; then
	if ((changed)); then
		run systemctl restart "$SERVICE"
	else
		ok "$SERVICE enabled and running"
	fi
else
	run systemctl enable --now "$SERVICE"
fi
