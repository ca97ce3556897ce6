#!/bin/sh
# Take paraview/doc/properties_panel.png: the ParaView GUI under Xvfb (whose -fbdir option
# keeps the screen in an XWD file), started with panel_screenshot.py; after WAIT seconds the
# screen is copied, ParaView is stopped and the property panel is cut out as a PNG.
# Usage (from the repository root, after cargo build --release):
#   T2TF_VOLUME=../shared/data/volumes/neghip_64x64x64_uint8.raw \
#   T2TF_MODEL=tests/fixtures/clip/quick_gelu T2TF_TOKENIZER=../shared/data/clip/tokenizer.json \
#   sh paraview/doc/take_panel_screenshot.sh [OUT.png]
set -eu
here=$(cd "$(dirname "$0")" && pwd)
out=${1:-$here/properties_panel.png}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
mkdir -p "$work/fb" "$work/config/ParaView"
# A fresh settings folder without the welcome dialog (it would cover the panel).
printf '[General]\nGeneralSettings.ShowWelcomeDialog=0\n' > "$work/config/ParaView/ParaView5.11.0.ini"
export XDG_CONFIG_HOME="$work/config"
export PYTHONPATH="$here/../compat" T2TF_PLUGIN="$here/../t2tf_plugin.py"
export T2TF_BIN="${T2TF_BIN:-$(pwd)/target/release/t2tf}"
export WORK="$work" WAIT="${WAIT:-45}"
xvfb-run -a -s "-screen 0 1600x1200x24 -fbdir $work/fb" sh -c '
  paraview -geometry 1600x1200+0+0 --script="$PWD/paraview/doc/panel_screenshot.py" \
    > "$WORK/paraview.log" 2>&1 &
  pid=$!
  sleep "$WAIT"
  cp "$WORK/fb/Xvfb_screen0" "$WORK/screen.xwd"
  kill $pid; wait $pid || true'
python3 "$here/xwd_to_png.py" "$work/screen.xwd" "$out" "${CROP:-0,140,1280,1160}"
echo "wrote $out"
