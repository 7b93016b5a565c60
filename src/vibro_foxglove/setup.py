from setuptools import find_packages, setup

package_name = "vibro_foxglove"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="vibro maintainers",
    maintainer_email="vibro@example.com",
    description=("Foxglove bridge node: the vibro graph live in Foxglove (camera images, ROI annotations, track, "
                 "impacts, fits)."),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "foxglove_bridge = vibro_ros.entry:foxglove_bridge",
        ],
    },
)
