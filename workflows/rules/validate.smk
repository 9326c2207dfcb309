# validate_config: snakemake.utils.validate (which also fills in the schema's
# defaults) with a short error that names the offending key, instead of the
# whole schema and config.
import os

import jsonschema
from snakemake.utils import validate


def validate_config(data, schema, key="config"):
    """Validate `data` against workflows/schemas/<schema>.schema.yaml, filling in defaults.

    Raises WorkflowError("<key>: <path>: <what is wrong>") on invalid data.
    """
    path = os.path.join(workflow.basedir, "workflows", "schemas", f"{schema}.schema.yaml")
    try:
        validate(data, path)
    except WorkflowError as err:
        cause = err.__cause__ or err.__context__
        if not isinstance(cause, jsonschema.ValidationError):
            raise
        best = jsonschema.exceptions.best_match([cause])  # the most specific error of anyOf / if-then
        where = "/".join(str(part) for part in best.absolute_path) or "(top level)"
        message = best.message if len(best.message) <= 300 else best.message[:300] + " ..."
        raise WorkflowError(f"invalid {key} ({schema}.schema.yaml): {where}: {message}") from None
