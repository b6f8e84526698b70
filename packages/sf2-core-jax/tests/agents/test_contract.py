"""The agents' framework-independent contract (`sf2_testing.contract`: bad input refused before anything is
built, presets, seeds, the schedule, configs equal across frameworks), run on the JAX agents (`agent_core`,
conftest.py)."""

from sf2_testing.contract import (  # noqa: F401 (pytest collects the imported tests)
    test_bad_input_is_refused_before_anything_is_built,
    test_ppo_presets_equal_across_frameworks,
    test_presets,
    test_presets_equal_across_frameworks,
    test_schedule_and_seeds,
)
