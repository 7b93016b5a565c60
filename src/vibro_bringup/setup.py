from glob import glob

from setuptools import find_packages, setup

package_name = "vibro_bringup"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/vibro_bringup/launch", glob("launch/*.launch.py")),
        ("share/vibro_bringup/config", glob("config/*.yaml") + glob("config/*.foxglove-layout.json")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="vibro maintainers",
    maintainer_email="vibro@example.com",
    description="Launch files, parameters, the node table and the graph runner.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
        ],
    },
)
