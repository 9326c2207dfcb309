# validate_config: the config against a schema of workflows/schemas/ with the option
# lists of ddsolve.options injected (ddstudies.workflow.load_schema), filling in the
# schema's defaults; a short error that names the offending key.
import os

from ddstudies import workflow as studies_workflow


def schema_path(schema):
    return os.path.join(workflow.basedir, "workflows", "schemas", f"{schema}.schema.yaml")


def validate_config(data, schema, key="config"):
    """Validate `data` against workflows/schemas/<schema>.schema.yaml, filling in defaults.

    Raises WorkflowError("invalid <key> (<schema>.schema.yaml): <path>: <what is wrong>").
    """
    try:
        studies_workflow.validate(data, schema_path(schema), key=key)
    except studies_workflow.ConfigError as err:
        raise WorkflowError(str(err)) from None


def validate_study(data):
    """Validate a single-study config against the schema of its `kind`; the kind."""
    kind = data.get("kind")
    if kind not in studies_workflow.SCHEMAS:
        raise WorkflowError(f"invalid config: kind: {kind!r} is not one of {list(studies_workflow.SCHEMAS)} "
                            f"(every single-study config names its kind)")
    validate_config(data, studies_workflow.SCHEMAS[kind])
    return kind
