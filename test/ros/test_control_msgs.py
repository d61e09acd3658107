"""Issue 28: the control_msgs interfaces scripts/bootstrap builds (interfaces/control_msgs) have
the type hashes (RIHS01, REP 2011) of control_msgs for ROS 2 Kilted, so that a MoveIt or a
dashboard of a full ROS install talks to the controller unchanged.

Where the expected hashes come from:

* PUBLISHED: read off public builds of control_msgs: the generated C type descriptions
  (`follow_joint_trajectory__description.c`, `query_trajectory_state__description.c`) of a
  control_msgs 5.x workspace, for the types whose fields have not changed since; and
  `ros2 topic info -v` of a joint_trajectory_controller's `controller_state` on a ROS 2 install
  with control_msgs >= 5.3 (the speed_scaling_factor field, as in Kilted's 6.x).
* KILTED_FEEDBACK: control_msgs 6.3.0 (June 2025, released into Kilted) added `index` and
  `multi_dof_index` to the action's feedback, which changes the hashes of the feedback, the
  feedback message and the action; no published value was found, so these were computed with
  Kilted's rosidl_generator_type_description (4.9.5, the wheel in .venv) from control_msgs
  6.4.0's FollowJointTrajectory.action. `test_the_generator_reproduces_the_published_hashes`
  checks that the same generator on these files without the 6.3 fields gives the published
  pre-6.3 values.
"""
import json
import pathlib
import shutil

import pytest

pytest.importorskip('control_msgs.action')

REPO = pathlib.Path(__file__).resolve().parents[2]

PUBLISHED = {
    'control_msgs/msg/JointTolerance':
        'RIHS01_c254f9cece0f3b733017b6990fd46d1326e25242d6b8844398c97d9a88e7d648',
    'control_msgs/msg/JointComponentTolerance':
        'RIHS01_739ea7566931944d33830fa10f1bf5e7a7fbdc3172bce7a7eaac642bd6e3ffa4',
    'control_msgs/msg/JointTrajectoryControllerState':
        'RIHS01_51d8dd89cc624cbe9daaeeb4d80d6de9b86168ffdc3be41fefc0953e3c26e480',
    'control_msgs/srv/QueryTrajectoryState':
        'RIHS01_4a0935dffef18bc5b9e101c9d03d84e681ecd4cebd724b8f11fde008751a325a',
    'control_msgs/action/FollowJointTrajectory_Goal':
        'RIHS01_8a9060704b269608f5a340934cc26e66869dd14bdac29e2e7fd9ec8b9882d205',
    'control_msgs/action/FollowJointTrajectory_Result':
        'RIHS01_8002e99ed2c14c6faa522f2a93c26d744c5982f254f9e98ff9c6f19789bdb220',
    'control_msgs/action/FollowJointTrajectory_SendGoal':
        'RIHS01_b13789dddc325a7a962825c45e28c77d37237ec129dd0c34dc5994562938c57f',
    'control_msgs/action/FollowJointTrajectory_SendGoal_Request':
        'RIHS01_179c93691f1f6d1d115881ff88c3917b7cc6eac2ba4bf56766cc7c4389e19ef1',
    'control_msgs/action/FollowJointTrajectory_SendGoal_Response':
        'RIHS01_e6a48ba740ae254500129a877f0b071be8663a115da1a539b74599cc97921fbf',
    'control_msgs/action/FollowJointTrajectory_GetResult':
        'RIHS01_e3ceb38e3e1867c8dc0f46014df26e90eb93422f27e9e97f936e07f94be4bc8b',
    'control_msgs/action/FollowJointTrajectory_GetResult_Request':
        'RIHS01_ecf7ea8463d3beec7084bca75216d0b01b87b6e1e4e09679bb26093041efcbe9',
    'control_msgs/action/FollowJointTrajectory_GetResult_Response':
        'RIHS01_08eefbaa146ce02ba45898d5e99160afd6c4c54a30d159aee0f2ca6035b1580f',
}
KILTED_FEEDBACK = {
    'control_msgs/action/FollowJointTrajectory_Feedback':
        'RIHS01_0bb018d181bdc6384dd75365480967bd1d6eaee4ef3dd597c64cd0b8bdc10867',
    'control_msgs/action/FollowJointTrajectory_FeedbackMessage':
        'RIHS01_95618cc73912d99b9acaa17d2da5e832cb0bfdeede7534fa8ec600feca2a6c4b',
    'control_msgs/action/FollowJointTrajectory':
        'RIHS01_ff29901b2693f5deb847e96084a1c2cdb26e70b7c847be21859b70a55fb29cf0',
}
# Published, before 6.3.0 (the same generated C files as above)
PRE_63_FEEDBACK = {
    'control_msgs/action/FollowJointTrajectory_Feedback':
        'RIHS01_3fd0aaecf71725121ae1ff7f01098a5e0da581e672be18a6b2c286cb43d96b49',
    'control_msgs/action/FollowJointTrajectory_FeedbackMessage':
        'RIHS01_80398fcb9674a79081a9906e2ccf0c804dd7cb15e22e362e606ee87186beab71',
    'control_msgs/action/FollowJointTrajectory':
        'RIHS01_738ebcb7a2d7cfa42f9f1001cc99ce3a4383d1cfe508015d9be8485e4b1c66f6',
}
EXPECTED = PUBLISHED | KILTED_FEEDBACK


def _hashes(json_dir: pathlib.Path) -> dict:
    """Every type hash the type description files under `json_dir` state."""
    found = {}
    for path in json_dir.rglob('*.json'):
        for entry in json.loads(path.read_text())['type_hashes']:
            found[entry['type_name']] = entry['hash_string']
    return found


def test_the_built_interfaces_have_control_msgs_kilted_type_hashes():
    from ament_index_python.packages import get_package_share_directory
    share = pathlib.Path(get_package_share_directory('control_msgs'))
    found = _hashes(share)
    assert {name: found.get(name) for name in EXPECTED} == EXPECTED


def test_the_hash_on_the_wire_is_the_same(rclpy_session):
    """What a subscriber of a full ROS install compares (`ros2 topic info -v`): the hash the
    middleware announces for a publisher of the built types."""
    from control_msgs.action import FollowJointTrajectory
    from control_msgs.msg import JointTrajectoryControllerState
    node = rclpy_session.create_node('type_hash_probe')
    try:
        for msg_type, topic in ((JointTrajectoryControllerState, 'state'),
                                (FollowJointTrajectory.Impl.FeedbackMessage, 'feedback')):
            node.create_publisher(msg_type, topic, 1)
            (info,) = node.get_publishers_info_by_topic(topic)
            name = info.topic_type
            assert str(info.topic_type_hash) == EXPECTED[name], name
    finally:
        node.destroy_node()


def test_the_generator_reproduces_the_published_hashes(tmp_path):
    """rosidl's generator on interfaces/control_msgs without the fields control_msgs 6.3 added
    gives the published pre-6.3 hashes: what computed KILTED_FEEDBACK is right, and the files'
    fields are control_msgs' (comments, which are the project's own, do not count)."""
    from rosidl_adapter import convert_to_idl
    from rosidl_generator_type_description import generate_type_hash
    from ament_index_python.packages import get_package_share_directory
    src = tmp_path / 'control_msgs'
    shutil.copytree(REPO / 'interfaces' / 'control_msgs', src)
    action = src / 'action' / 'FollowJointTrajectory.action'
    lines = action.read_text().splitlines()
    assert 'int32 index' in lines and 'int32 multi_dof_index' in lines
    action.write_text('\n'.join(x for x in lines if x not in ('int32 index',
                                                              'int32 multi_dof_index')) + '\n')
    idl = []
    for f in sorted(src.glob('*/*.*')):
        if f.suffix in ('.msg', '.srv', '.action'):
            out = convert_to_idl(src, 'control_msgs', f.relative_to(src), tmp_path / 'idl')
            idl.append(f'{tmp_path / "idl"}:{out.relative_to(tmp_path / "idl")}')
    deps = ('std_msgs', 'trajectory_msgs', 'builtin_interfaces', 'geometry_msgs',
            'unique_identifier_msgs', 'service_msgs', 'action_msgs')
    args = tmp_path / 'args.json'
    args.write_text(json.dumps({
        'package_name': 'control_msgs', 'output_dir': str(tmp_path / 'json'), 'idl_tuples': idl,
        'include_paths': [f'{d}:{get_package_share_directory(d)}' for d in deps]}))
    generate_type_hash(str(args))
    found = _hashes(tmp_path / 'json')
    want = PUBLISHED | PRE_63_FEEDBACK
    assert {name: found.get(name) for name in want} == want


def test_the_result_codes_are_control_msgs():
    from control_msgs.action import FollowJointTrajectory
    from motion_ctrl.core import follow_goal as fg
    r = FollowJointTrajectory.Result
    assert (fg.SUCCESSFUL, fg.INVALID_GOAL, fg.INVALID_JOINTS, fg.OLD_HEADER_TIMESTAMP,
            fg.PATH_TOLERANCE_VIOLATED, fg.GOAL_TOLERANCE_VIOLATED) == (
        r.SUCCESSFUL, r.INVALID_GOAL, r.INVALID_JOINTS, r.OLD_HEADER_TIMESTAMP,
        r.PATH_TOLERANCE_VIOLATED, r.GOAL_TOLERANCE_VIOLATED)
