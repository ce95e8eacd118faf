"""msg_docs/ describes the live nodes: topics (name, type, direction), parameters (type, default, range) and
services, read from the ROS graph and the parameter services of the running nodes."""
import ast
import re
from pathlib import Path

import pytest

from ros_helpers import DISCOVERY_TIMEOUT, NodeProcess, describe_all_params, get_params, spin_until

DOCS = Path(__file__).resolve().parents[1] / "msg_docs"
# parameters and services every rclpy node has, which the pages do not repeat
STANDARD_PARAMS = {"use_sim_time", "start_type_description_service"}
STANDARD_SERVICE_SUFFIXES = ("describe_parameters", "get_parameter_types", "get_parameters", "list_parameters",
                             "set_parameters", "set_parameters_atomically", "get_type_description")
TYPE_NAMES = {1: "bool", 2: "int", 3: "double", 4: "string", 9: "string[]"}


def tables(page: Path) -> dict:
    """{section: [row dict]} for the markdown tables under each '## ' heading."""
    out, section, header = {}, None, None
    for line in page.read_text().splitlines():
        if line.startswith("## "):
            section, header = line[3:].strip().lower(), None
            out[section] = []
            continue
        if not line.startswith("|") or section is None:
            continue
        cells = [c.strip() for c in re.split(r"(?<!\\)\|", line.strip())[1:-1]]
        if header is None:
            header = [c.lower() for c in cells]
        elif not set("".join(cells)) <= set("-: "):
            out[section].append(dict(zip(header, cells)))
    return out


def name(cell: str) -> str:
    return cell.strip("`")


def absolute(topic: str) -> str:
    return topic if topic.startswith("/") else "/" + topic


def message_class(type_name: str):
    pkg, kind, cls = type_name.split("/")
    return getattr(__import__(f"{pkg}.{kind}", fromlist=[cls]), cls)


NODES = {
    "sim_node": ["flagbot_sim.ros.sim_node"],
    "beam_node": ["flagbot_sim.ros.beam_node"],
    "cmd_profile": ["flagbot_sim.ros.cmd_profile", "constant", "0"],
}


@pytest.mark.parametrize("node_name", list(NODES))
def test_page_matches_the_live_node(ros, node_name):
    doc = tables(DOCS / f"{node_name}.md")
    proc = NodeProcess(*NODES[node_name])
    try:
        spin_until(ros, lambda: node_name in ros.get_node_names(), DISCOVERY_TIMEOUT, node_name)
        documented = {(absolute(name(r["topic"])), r["direction"], r["type"]) for r in doc["topics"]}
        if node_name == "sim_node":
            # /tf and /tf_static have their own section: live only where tf2_msgs is installed
            from flagbot_sim.ros.tf_derive import tf_message_class
            from flagbot_sim.topics import SIM_TF
            tf_rows = doc["transforms (/tf, /tf_static)"]
            assert [name(r["topic"]) for r in tf_rows] == SIM_TF
            assert {r["type"] for r in tf_rows} == {"tf2_msgs/msg/TFMessage"}
            if tf_message_class() is not None:
                documented |= {(name(r["topic"]), "pub", r["type"]) for r in tf_rows}

        def live():
            pubs = ros.get_publisher_names_and_types_by_node(node_name, "/")
            subs = ros.get_subscriber_names_and_types_by_node(node_name, "/")
            return ({(t, "pub", ty[0]) for t, ty in pubs if not t.startswith("/rosout") and
                     not t.startswith("/parameter_events")} |
                    {(t, "sub", ty[0]) for t, ty in subs if not t.startswith("/parameter_events") and
                     t != "/clock"})
        # graph information arrives over discovery: wait until every documented endpoint has shown up
        spin_until(ros, lambda: documented <= live(), DISCOVERY_TIMEOUT, f"{node_name}'s documented topics")
        assert live() == documented
        # every field of each message type is described
        for r in doc["topics"]:
            for field in message_class(r["type"]).get_fields_and_field_types():
                assert f"`{field}`" in r["fields"], f"{r['topic']}: field {field} not described"
        # services: discovered on their own schedule (a loaded machine showed the topics before them)
        def services():
            return {(s, ty[0]) for s, ty in ros.get_service_names_and_types_by_node(node_name, "/")
                    if not s.endswith(STANDARD_SERVICE_SUFFIXES)}
        # a page writes a private service as ~/name: the node's own namespace, /<node name>/name
        documented_services = {(f"/{node_name}/{name(r['service'])[2:]}" if name(r["service"]).startswith("~/")
                                else f"/{name(r['service'])}", r["type"]) for r in doc["services"]}
        spin_until(ros, lambda: documented_services <= services(), DISCOVERY_TIMEOUT, f"{node_name}'s services")
        assert services() == documented_services
        # parameters: names, types, defaults and ranges
        descs = {k: v for k, v in describe_all_params(ros, node_name).items() if k not in STANDARD_PARAMS}
        documented_params = {name(r["parameter"]): r for r in doc["parameters"]}
        assert set(descs) == set(documented_params)
        values = get_params(ros, node_name, list(descs))
        for pname, r in documented_params.items():
            d = descs[pname]
            assert TYPE_NAMES[d.type] == r["type"], pname
            default = r["default"]
            expected = {"true": True, "false": False, '""': ""}.get(default, default)
            if r["type"] in ("double", "int"):
                expected = float(default)
            elif r["type"] == "string[]":
                expected = ast.literal_eval(default)
            got = values[pname]
            assert (list(got) if r["type"] == "string[]" else got) == expected, pname
            rng = d.floating_point_range or d.integer_range
            if r["range"] not in ("-", ""):
                if rng:
                    lo, hi = (float(x) for x in r["range"].split(".."))
                    assert (rng[0].from_value, rng[0].to_value) == (lo, hi), pname
                else:
                    assert all(c.strip() in d.additional_constraints for c in r["range"].split(",")), pname
            else:
                assert not rng, f"{pname} has a range the page does not give"
    finally:
        code, out = proc.stop()
    assert code == 0 and "Traceback" not in out, out
