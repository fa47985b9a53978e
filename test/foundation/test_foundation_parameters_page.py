"""docs/PARAMETERS.md is what the nodes declare: written from their ParamSpecs, never by hand."""
from tacforce_ros.nodes import parameters_page


def test_the_parameters_page_is_written_from_the_declarations():
    assert parameters_page.PAGE.read_text() == parameters_page.markdown(), (
        'docs/PARAMETERS.md is out of date: ./run.sh exec python -m '
        'tacforce_ros.nodes.parameters_page')


def test_every_node_of_a_session_has_its_section():
    from tacforce_ros.bringup.session_plan import MODES, SessionArgs, plan
    page = parameters_page.markdown()
    planned = {node.executable for mode in MODES for node in plan(SessionArgs(mode=mode))
               if node.executable != 'robot_state_publisher'}
    assert planned and all(f'## {name}\n' in page for name in planned), planned
