from setuptools import find_packages, setup

package_name = "vibro_ros"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={package_name: ["fastdds_profile.xml"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="vibro maintainers",
    maintainer_email="vibro@example.com",
    description=("ROS 2 plumbing shared by the vibro nodes: topic table, QoS profiles, node support (parameters, "
                 "diagnostics, shutdown), result collection, rosbag2/MCAP bag I/O "
                 "and the recorder and bag_source nodes."),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "recorder = vibro_ros.entry:recorder",
            "bag_source = vibro_ros.entry:bag_source",
        ],
    },
)
