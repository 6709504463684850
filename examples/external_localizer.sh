#!/bin/sh
# dockbench external localizer (JSON-lines protocol 1) in POSIX sh: a baseline that
# always reports the same distance. Shows the whole protocol with no JSON library:
# dockbench writes compact JSON ("key":value, no spaces), one request per line.
#
#   dockbench evaluate DATASET -l "exec:sh examples/external_localizer.sh 5.0" -o OUT
#
# Replace the frame branch with a call to your own tool, e.g.
#   result=$(my_detector "$image")   # prints a distance or nothing
DIST=${1:-5.0}
while IFS= read -r line; do
  case $line in
    *'"type":"reset"'*)
      case $line in
        *'"protocol":1,'*|*'"protocol":1}'*) printf '{"ok":true,"protocol":1,"name":"const-sh"}\n' ;;
        *) printf '{"ok":false,"error":"unsupported protocol"}\n' ;;
      esac ;;
    *'"type":"frame"'*)
      index=$(printf '%s\n' "$line" | sed -n 's/.*"index":\([0-9-]*\).*/\1/p')
      image=$(printf '%s\n' "$line" | sed -n 's/.*"image":"\([^"]*\)".*/\1/p')
      if [ -r "$image" ]; then
        printf '{"ok":true,"index":%s,"distance":%s}\n' "$index" "$DIST"
      else
        printf '{"ok":false,"index":%s,"error":"cannot read image"}\n' "$index"
      fi ;;
    *) printf '{"ok":false,"error":"unknown request"}\n' ;;
  esac
done
