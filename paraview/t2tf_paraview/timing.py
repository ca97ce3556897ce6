"""The Time Estimate property: how long the applied Steps and Views take, from what the last
run with the same model measured (runs of one model on one machine take about the same time
per step and view; the first step and the start-up are one-off work)."""
import json

# The timing the last run with each model measured, for this session (model -> measured()).
_by_model = {}


def measured(report, views, wall_seconds):
    """What a run measured: the median time of one step per view (steps after the first,
    which carries one-off work), and the start-up (the run's wall time less its steps: model
    loading, caption embeddings, output). None without two timed steps."""
    try:
        steps = [float(s["seconds"]) for s in json.loads(report)["steps"]]
    except (ValueError, KeyError, TypeError):
        return None
    later = sorted(steps[1:])
    if not later or views < 1:
        return None
    per_step = later[len(later) // 2]
    return {"per_view_step": per_step / views,
            "start": max(0.0, wall_seconds - sum(steps))}


def remember(model, timing):
    if timing:
        _by_model[model] = timing


def for_model(model):
    return _by_model.get(model)


def _seconds(value):
    if value >= 120:
        return "%.0f min" % (value / 60.0)
    if value >= 10:
        return "%.0f s" % value
    return "%.1f s" % value


def estimate(steps, views, timing):
    """The Time Estimate text for `steps` x `views` from a measured() timing."""
    if not timing:
        return "known after the first run with this model"
    each = timing["per_view_step"]
    total = steps * views * each + timing["start"]
    ms = 1000.0 * each
    # The total last: the panel's read-only field shows a long text's end.
    return "%d steps x %d views x %s ms + %s start = about %s" % (
        steps, views, "%.1f" % ms if ms < 10 else "%.0f" % ms, _seconds(timing["start"]),
        _seconds(total))
