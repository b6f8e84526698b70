# Sourced by run.sh and speed.sh (repo root): installs the example's wheels ($PGX_EXAMPLE/wheels, default
# .pgx-example) once per host into /tmp/pgxsite (several lanes at once take turns on a lock); sets `example`
# to the example's folder. The caller puts /tmp/pgxsite and the stand-ins on PYTHONPATH where it runs the example.
example=${PGX_EXAMPLE:-.pgx-example}
(
  flock 9
  if [ ! -f /tmp/pgxsite/.done ]; then
    python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/pgxsite "$example"/wheels/*.whl && touch /tmp/pgxsite/.done
  fi
) 9> /tmp/pgxsite.lock
