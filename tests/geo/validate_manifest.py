"""Validates manifest.json files against docs/manifest.schema.json with the `jsonschema`
package (Draft 2020-12). Usage: validate_manifest.py SCHEMA MANIFEST...; prints one line per
error and exits 1 when any manifest is invalid."""
import json
import sys

import jsonschema

schema = json.load(open(sys.argv[1]))
jsonschema.Draft202012Validator.check_schema(schema)
validator = jsonschema.Draft202012Validator(schema)
bad = 0
for path in sys.argv[2:]:
    for e in validator.iter_errors(json.load(open(path))):
        bad += 1
        print(f"{path}: {'/'.join(map(str, e.absolute_path))}: {e.message}")
sys.exit(1 if bad else 0)
