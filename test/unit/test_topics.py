"""The topic contract is consistent and the README shows it verbatim."""

from __future__ import annotations

from vesselbot_ros import topics


def test_topic_keys_and_names_are_unique():
    keys = [t.key for t in topics.TOPICS]
    names = [t.name for t in topics.TOPICS]
    assert len(set(keys)) == len(keys)
    assert len(set(names)) == len(names)
    assert all(n.startswith("/") for n in names)


def test_every_publisher_is_a_known_node_role():
    roles = set(topics.NODE_NAMES) | {"all"}
    assert {t.publisher for t in topics.TOPICS} <= roles
    assert {s.server for s in topics.SERVICES} <= roles


def test_readme_topic_table_matches_the_contract(repo):
    readme = (repo / "README.md").read_text()
    assert topics.markdown_table() in readme, "regenerate the README table from vesselbot_ros.topics.markdown_table()"
